"""Radial kernels and the product kernel on the augmented domain ``(xi, mu, dT)``.

A radial kernel is ``k(x, y) = phi(|x - y|)`` with a shape parameter ``eps``.
For the gradient Hermite–Birkhoff problem we need derivatives of ``k`` in the
state block only.  Write ``d = x - y``, ``r = |d|`` and

* ``A(r) = phi'(r) / r``,
* ``B(r) = (phi''(r) - A(r)) / r**2 = 2 dA/d(r**2)``,
* ``C(r) = 2 dB/d(r**2)``.

Then (chain rule with ``d r**2 / d x_a = 2 d_a`` and ``d r**2 / d y_a = -2 d_a``)

* ``d/dy_b k = -A d_b``                                              (value of a representer),
* ``d/dx_a d/dy_b k = -B d_a d_b - A delta_ab``                     (Gramian block, gradient of ``s``),
* ``d/dx_c d/dx_a d/dy_b k = -C d_a d_b d_c - B (delta_ac d_b + delta_bc d_a + delta_ab d_c)``
  (Hessian of ``s``).

The factors of the three families (shape ``e = eps``, ``E = exp(-e r)``):

=============  ==========================  =====================  ==========================
kernel         A                           B                      C
=============  ==========================  =====================  ==========================
IMQ            ``-e^2 u^(-3/2)``            ``3 e^4 u^(-5/2)``      ``-15 e^6 u^(-7/2)``
Matérn 5/2     ``-(e^2/3)(1 + e r) E``      ``(e^4/3) E``           ``-(e^5/3) E / r``
Matérn 3/2     ``-e^2 E``                   ``e^3 E / r``           ``-e^3 (1 + e r) E / r^3``
=============  ==========================  =====================  ==========================

with ``u = 1 + e^2 r^2`` for the IMQ.  Where a factor is singular at ``r = 0``
it always multiplies enough powers of ``d`` for the product to vanish there
(Matérn 5/2 is ``C^4``); we return 0 for ``r`` below a tiny threshold.  Matérn
3/2 is only ``C^2``: its third derivatives are bounded but not continuous at
the centres, and the value returned there (0) is one admissible choice.

Two modifications of the state kernel live here too, each defined once:
:class:`PeriodicCoordinates` (a periodic factor for angles) and
:class:`StateSymmetry` (the group average ``sum_g k(x, g y)`` over a finite
orthogonal group, whose derivatives are weighted sums of the plain ones).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from sympredict._numba import compilable
from sympredict.base import Parametrized


__all__ = [
    "RadialKernel",
    "IMQ",
    "Matern32",
    "Matern52",
    "ProductKernel",
    "PeriodicCoordinates",
    "StateSymmetry",
    "KERNEL_FAMILIES",
    "register_family",
    "kernel_from_spec",
    "pairwise_distances",
]

#: Shape parameters are limited to [1e-50, 1e50]: the derivative factors contain
#: ``eps**6``, which must stay a finite, normal float64.
_EPS_RANGE = (1e-50, 1e50)

#: ``exp(-x)`` underflows to 0 beyond this; arguments are clamped to it so that
#: ``(1 + eps r) exp(-eps r)`` is 0, not ``inf * 0``, at enormous distances.
_EXP_CLAMP = 745.0

#: Below this distance the factors that are singular at ``r = 0`` are set to 0;
#: the products they enter are then ``O(r)`` or smaller and already below
#: round-off, while ``1/r**3`` of a larger ``r`` cannot overflow.
_R_TINY = 1e-100


class RadialKernel(Parametrized):
    """Base class of radial kernels ``k(x, y) = phi(eps * |x - y|)``.

    A family is one subclass that defines its formulas once, as static
    methods of ``(e, r)`` (shape parameter, distance) written with arithmetic,
    ``np.sqrt``, ``np.exp``, ``np.minimum`` and ``np.maximum`` only, so that
    the same function runs on NumPy arrays here and, compiled by numba, on
    scalars in :mod:`sympredict.kernels._compiled`:

    * :meth:`profile`: ``phi(r)``;
    * :meth:`first_factors`: ``(A, B)``;
    * :meth:`all_factors`: ``(A, B, C)``.

    Registering the class in :data:`KERNEL_FAMILIES` (the
    :func:`register_family` decorator) makes it available by name in files,
    the CLI and model selection, and to the compiled paths.

    Parameters
    ----------
    eps
        Shape parameter, a finite positive float.  Larger ``eps`` means a
        narrower kernel.
    """

    #: Short name used in files and specs.
    name: str = "radial"

    #: Whether the formulas use only ``+ - * /`` and ``sqrt`` (each correctly
    #: rounded in every implementation), so that compiled code reproduces
    #: NumPy's values bit for bit; ``exp`` differs between NumPy's SIMD and libm.
    exact_arithmetic: bool = False

    def __init__(self, eps: float):
        try:
            eps = float(eps)
        except (TypeError, ValueError):
            raise ValueError(f"{type(self).__name__}: eps must be a positive float, got {eps!r}") from None
        if not np.isfinite(eps) or eps <= 0:
            raise ValueError(f"{type(self).__name__}: eps must be a finite positive float, got {eps!r}")
        if not _EPS_RANGE[0] <= eps <= _EPS_RANGE[1]:
            raise ValueError(
                f"{type(self).__name__}: eps must lie in [{_EPS_RANGE[0]:.0e}, {_EPS_RANGE[1]:.0e}] "
                f"(eps**6 enters the derivatives), got {eps!r}"
            )
        self.eps = eps

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.eps!r})"

    def __eq__(self, other) -> bool:
        return type(self) is type(other) and self.eps == other.eps

    def __hash__(self) -> int:
        return hash((type(self).__name__, self.eps))

    def set_params(self, **params) -> "RadialKernel":
        """A new kernel with the given parameters changed (kernels are immutable values)."""
        valid = self._param_names()
        unknown = sorted(set(params) - set(valid))
        if unknown:
            raise ValueError(f"{type(self).__name__} has no parameter(s) {unknown}; valid parameters: {valid}")
        return type(self)(**{**self.get_params(deep=False), **params})

    @property
    def spec(self) -> dict:
        """A JSON/HDF5-friendly description ``{'family': name, 'eps': eps}``."""
        return {"family": self.name, "eps": self.eps}

    # --- the family's formulas (static: shared with the compiled code) ---
    @staticmethod
    def profile(e, r):
        """``phi(r)`` for shape ``e``; elementwise on arrays, or on scalars in compiled code."""
        raise NotImplementedError

    @staticmethod
    def first_factors(e, r):
        """``(A, B)`` at distance ``r`` (see the module docstring)."""
        raise NotImplementedError

    @staticmethod
    def all_factors(e, r):
        """``(A, B, C)`` at distance ``r``."""
        raise NotImplementedError

    # --- profile and derivative factors, all elementwise in ``r >= 0`` ---
    def phi(self, r: np.ndarray) -> np.ndarray:
        """Kernel profile ``phi(r)``, elementwise."""
        return self.profile(self.eps, np.asarray(r, dtype=float))

    def factors(self, r: np.ndarray, order: int = 2):
        """Derivative factors ``(A, B)`` (``order=2``) or ``(A, B, C)`` (``order=3``).

        Parameters
        ----------
        r : ndarray, any shape
            Distances ``|x - y| >= 0``.
        order
            2 for the Gramian block / gradient of the surrogate, 3 when the
            Hessian of the surrogate is needed as well.

        Returns
        -------
        tuple of ndarray, each of the shape of ``r``
        """
        r = np.asarray(r, dtype=float)
        if order == 2:
            return self.first_factors(self.eps, r)
        return self.all_factors(self.eps, r)

    # --- matrix-valued helpers ---
    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Kernel matrix ``k(x_i, y_j)``.

        Parameters
        ----------
        x, y : ndarray of shapes (Nx, d) and (Ny, d)

        Returns
        -------
        ndarray of shape (Nx, Ny)
        """
        return self.phi(pairwise_distances(x, y))

    def state_gramian(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Generalized Gramian blocks ``d/dx_a d/dy_b k(x_i, y_j)``.

        Parameters
        ----------
        x : ndarray of shape (Nx, d)
        y : ndarray of shape (Ny, d)

        Returns
        -------
        ndarray of shape (Nx, Ny, d, d)
            ``-B d_a d_b - A delta_ab`` with ``d = x_i - y_j``.

        Notes
        -----
        Memory ``O(Nx Ny d^2)``: a reference for small sets; the greedy builds
        single columns instead.
        """
        diff = x[:, None, :] - y[None, :, :]
        r = np.sqrt(np.einsum("ija,ija->ij", diff, diff))
        A, B = self.factors(r, order=2)
        dim = x.shape[1]
        return -B[..., None, None] * diff[..., :, None] * diff[..., None, :] - A[..., None, None] * np.eye(dim)


def pairwise_distances(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Euclidean distances ``|x_i - y_j|`` of shape (Nx, Ny), from explicit differences.

    The differences are formed explicitly (not by the ``|x|^2 - 2 x.y + |y|^2``
    expansion) so that tiny distances keep full relative accuracy.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    if y.ndim == 1:
        y = y[:, None]
    diff = x[:, None, :] - y[None, :, :]
    return np.sqrt(np.einsum("ija,ija->ij", diff, diff))


@compilable
def _inverse_r(r):
    """``1/r``, and 0 where ``r < _R_TINY`` (on arrays and on compiled scalars alike)."""
    return (r >= _R_TINY) / np.maximum(r, _R_TINY)


#: The kernel families by name (as used in specs, files, the CLI and the compiled code).
KERNEL_FAMILIES: dict = {}


def register_family(cls):
    """Class decorator: make a :class:`RadialKernel` subclass available by its ``name``."""
    if not (isinstance(cls, type) and issubclass(cls, RadialKernel)) or cls.name in KERNEL_FAMILIES:
        raise ValueError(
            f"cannot register {cls!r}: not a RadialKernel subclass, or the name {getattr(cls, 'name', None)!r} is taken"
        )
    KERNEL_FAMILIES[cls.name] = cls
    return cls


@register_family
class IMQ(RadialKernel):
    """Inverse multiquadric ``phi(r) = (1 + eps^2 r^2)^(-1/2)`` (infinitely smooth)."""

    name = "imq"
    exact_arithmetic = True

    @staticmethod
    def profile(e, r):
        return 1.0 / np.sqrt(1.0 + (e * r) ** 2)

    @staticmethod
    def first_factors(e, r):
        e2 = e * e
        inv_u = 1.0 / (1.0 + e2 * r * r)
        sq = np.sqrt(inv_u)
        return -e2 * inv_u * sq, 3.0 * e2 * e2 * inv_u * inv_u * sq  # -e^2 u^(-3/2), 3 e^4 u^(-5/2)

    @staticmethod
    def all_factors(e, r):
        e2 = e * e
        inv_u = 1.0 / (1.0 + e2 * r * r)
        sq = np.sqrt(inv_u)
        A = -e2 * inv_u * sq
        B = 3.0 * e2 * e2 * inv_u * inv_u * sq
        C = -15.0 * e2 * e2 * e2 * (inv_u * inv_u * inv_u) * sq  # -15 e^6 u^(-7/2)
        return A, B, C


@register_family
class Matern52(RadialKernel):
    """Matérn 5/2 ``phi(r) = (1 + eps r + eps^2 r^2 / 3) exp(-eps r)`` (``C^4``)."""

    name = "matern52"

    @staticmethod
    def profile(e, r):
        er = np.minimum(e * r, _EXP_CLAMP)
        return (1.0 + er + er * er / 3.0) * np.exp(-er)

    @staticmethod
    def first_factors(e, r):
        er = np.minimum(e * r, _EXP_CLAMP)
        E = np.exp(-er)
        return -(e * e / 3.0) * (1.0 + er) * E, (e**4 / 3.0) * E

    @staticmethod
    def all_factors(e, r):
        er = np.minimum(e * r, _EXP_CLAMP)
        E = np.exp(-er)
        return -(e * e / 3.0) * (1.0 + er) * E, (e**4 / 3.0) * E, -(e**5 / 3.0) * E * _inverse_r(r)


@register_family
class Matern32(RadialKernel):
    """Matérn 3/2 ``phi(r) = (1 + eps r) exp(-eps r)`` (``C^2`` only).

    Its surrogate Hessian (third kernel derivatives) is bounded but
    discontinuous at the centres; Newton still converges, at a lower rate
    when an iterate sits on a centre.
    """

    name = "matern32"

    @staticmethod
    def profile(e, r):
        er = np.minimum(e * r, _EXP_CLAMP)
        return (1.0 + er) * np.exp(-er)

    @staticmethod
    def first_factors(e, r):
        er = np.minimum(e * r, _EXP_CLAMP)
        E = np.exp(-er)
        return -e * e * E, e**3 * E * _inverse_r(r)

    @staticmethod
    def all_factors(e, r):
        er = np.minimum(e * r, _EXP_CLAMP)
        E = np.exp(-er)
        inv_r = _inverse_r(r)
        return -e * e * E, e**3 * E * inv_r, -(e**3) * (1.0 + er) * E * (inv_r * inv_r * inv_r)


def kernel_from_spec(spec: Optional[dict]) -> Optional[RadialKernel]:
    """Rebuild a kernel from :attr:`RadialKernel.spec` (``None`` stays ``None``)."""
    if spec is None:
        return None
    try:
        cls = KERNEL_FAMILIES[spec["family"]]
    except KeyError:
        raise ValueError(
            f"unknown kernel family {spec.get('family')!r}; expected one of {sorted(KERNEL_FAMILIES)}"
        ) from None
    return cls(spec["eps"])


@dataclass(frozen=True)
class PeriodicCoordinates:
    """State coordinates that are angles: the periodic factor of the state kernel.

    For a coordinate ``i`` of period ``P`` the squared distance of the radial
    state kernel uses, instead of ``d_i^2`` (``d = x - y``), the squared chord

        ``u(d_i)^2 = (P / pi)^2 sin^2(pi d_i / P)``

    (the distance of the two angles embedded on a circle of circumference
    ``P``), so ``k`` is ``P``-periodic in ``x_i`` and in ``y_i``, equals the
    plain kernel to ``O(d^4)`` near the diagonal, and stays positive definite
    (a radial kernel restricted to the embedded circle).  Every derivative of
    ``k`` is the plain one with ``d_i`` replaced by ``g(d_i) = d(u^2 / 2)/d d_i``
    and the identity by ``diag(g'(d_i))`` (see :meth:`terms`):

    * ``d/dy_b k = -A g_b``,
    * ``d/dx_a d/dy_b k = -B g_a g_b - A g'_a delta_ab``,
    * ``d/dx_c d/dx_a d/dy_b k = -C g_a g_b g_c
      - B (g'_a g_b delta_ac + g'_b g_a delta_bc + g'_a g_c delta_ab) - A g''_a delta_ab delta_ac``,

    with ``g(d) = (P / 2 pi) sin(2 pi d / P)``, ``g' = cos(2 pi d / P)``,
    ``g'' = -(2 pi / P) sin(2 pi d / P)``; on the other coordinates ``g = d``,
    ``g' = 1``, ``g'' = 0`` gives the plain formulas back.

    Parameters
    ----------
    coordinates : tuple of int
        Distinct state indices (in ``0 .. 2n-1``) that are angles.
    periods : tuple of float
        Their periods, positive and finite, one per coordinate.
    """

    coordinates: tuple
    periods: tuple

    def __post_init__(self):
        coords, periods = tuple(self.coordinates), tuple(self.periods)
        if (
            not coords
            or len(coords) != len(periods)
            or len(set(coords)) != len(coords)
            or not all(isinstance(c, (int, np.integer)) and not isinstance(c, bool) and c >= 0 for c in coords)
        ):
            raise ValueError(
                f"periodic coordinates must be distinct non-negative integers, one period each; "
                f"got coordinates {self.coordinates!r}, periods {self.periods!r}"
            )
        if not all(
            isinstance(p, (int, float, np.number)) and not isinstance(p, bool) and np.isfinite(p) and p > 0
            for p in periods
        ):
            raise ValueError(f"periods must be positive finite numbers, got {self.periods!r}")
        object.__setattr__(self, "coordinates", tuple(int(c) for c in coords))
        object.__setattr__(self, "periods", tuple(float(p) for p in periods))

    @property
    def spec(self) -> dict:
        return {"coordinates": list(self.coordinates), "periods": list(self.periods)}

    @classmethod
    def from_spec(cls, spec) -> Optional["PeriodicCoordinates"]:
        """Rebuild from :attr:`spec` (``None`` stays ``None``); ``ValueError`` for a malformed spec."""
        if spec is None:
            return None
        if (
            not isinstance(spec, dict)
            or set(spec) != {"coordinates", "periods"}
            or not all(isinstance(spec[k], list) for k in spec)
        ):
            raise ValueError(f"malformed periodic-coordinates spec {spec!r}")
        return cls(tuple(spec["coordinates"]), tuple(spec["periods"]))

    def check_dim(self, dim: int) -> None:
        """``ValueError`` unless every coordinate is an index of a ``dim``-dimensional state."""
        if max(self.coordinates) >= dim:
            raise ValueError(f"periodic coordinates {self.coordinates} do not fit states of dimension {dim}")

    @staticmethod
    def formulas(d, period):
        """``(u, g, g', g'')`` of the differences ``d`` of one coordinate of period ``period`` (elementwise).

        ``u = (P / pi) sin(t)``, ``g = u cos(t)``, ``g' = cos(2 t)``,
        ``g'' = -(4 pi / P) sin(t) cos(t)`` with ``t = pi d / P``: the one
        definition of the periodic factor's formulas.
        """
        t = (np.pi / period) * d
        s, c = np.sin(t), np.cos(t)
        u = (period / np.pi) * s
        return u, u * c, c * c - s * s, (-4.0 * np.pi / period) * (s * c)

    def terms(self, diff: np.ndarray, order: int = 2):
        """Distances and the periodic replacements of the differences, for raw differences ``diff = x - y``.

        Parameters
        ----------
        diff : ndarray of shape (..., D)
        order
            1: ``(r, G)``; 2: ``(r, G, G1)``; 3: ``(r, G, G1, G2)``.

        Returns
        -------
        r : ndarray of shape (...)
            ``sqrt(sum_i u_i^2)`` (``u_i = d_i`` on the other coordinates).
        G, G1, G2 : ndarray of shape (..., D)
            ``g(d_i)``, ``g'(d_i)``, ``g''(d_i)`` (``d_i``, 1, 0 on the other coordinates).

        Notes
        -----
        ``O(size of diff)``; only the periodic columns call the trigonometric functions.
        """
        U = diff.copy()
        G = diff.copy()
        G1 = np.ones_like(diff) if order >= 2 else None
        G2 = np.zeros_like(diff) if order >= 3 else None
        for i, period in zip(self.coordinates, self.periods):
            u, g, g1, g2 = self.formulas(diff[..., i], period)
            U[..., i] = u
            G[..., i] = g
            if order >= 2:
                G1[..., i] = g1
            if order >= 3:
                G2[..., i] = g2
        r = np.sqrt(np.einsum("...a,...a->...", U, U))
        return (r, G) if order == 1 else (r, G, G1) if order == 2 else (r, G, G1, G2)

    def distances(self, diff: np.ndarray) -> np.ndarray:
        """``r`` of :meth:`terms` only, shape ``diff.shape[:-1]``."""
        return self.terms(diff, order=1)[0]

    def wrap(self, x: np.ndarray) -> np.ndarray:
        """``x`` with each periodic coordinate reduced to ``[-P/2, P/2)`` (a copy; the kernel cannot tell them apart)."""
        x = np.array(x, dtype=float)
        for i, period in zip(self.coordinates, self.periods):
            x[..., i] = np.mod(x[..., i] + 0.5 * period, period) - 0.5 * period
        return x


#: Tolerance of the orthogonality and closure checks of :class:`StateSymmetry` (entries are O(1)).
_GROUP_TOL = 1e-12


@dataclass(frozen=True, eq=False)
class StateSymmetry:
    """A finite group ``G`` of orthogonal maps of the state: the group-averaged (invariant) state kernel.

    The state kernel becomes

        ``k_G(x, y) = sum_{g in G} k(x, g y)``

    (``k`` radial, so ``k(x, g y) = k(g^T x, y)``; as ``G`` is closed under
    ``g -> g^T = g^-1``, ``k_G`` is symmetric and ``k_G(h x, y) = k_G(x, y)`` for
    every ``h in G``).  ``k_G`` is positive semi-definite (the kernel of the
    feature map ``x -> sum_g Phi(g x)``), and every function in its native space
    is ``G``-invariant: an interpolant ``s`` built from it satisfies
    ``s(g x) = s(x)`` exactly, so one centre acts for its ``|G|`` images.

    Hermite-Birkhoff functionals transform with the group: the derivative in
    ``y_b`` is

        ``d/dy_b k(x, g y) = sum_c g_cb (d/dz_c k)(x, z)|_{z = g y}``,

    a plain state-derivative functional of ``k`` at the image ``g y`` in the
    direction ``g e_b`` (column ``b`` of ``g``).  :meth:`terms` lists these
    images, components ``c`` and weights ``g_cb`` (nonzero only): the one
    definition that the Gramian columns (:mod:`sympredict.interpolation.functionals`), the
    surrogate and its Hessian (:mod:`sympredict.interpolation.surrogate`) use, so every
    derivative of ``k_G`` is a weighted sum of the plain formulas of the module
    docstring.  Signed permutations (e.g. sign flips ``diag(+-1)``) give one
    term per group element; a general orthogonal ``g`` up to ``2n``.

    At a point fixed by some ``g`` the functionals that ``g`` negates vanish
    in the invariant space (e.g. ``d/dq`` at ``q = 0`` for ``q -> -q``): their
    Gramian diagonal is 0, which the greedy's power guard skips.

    Parameters
    ----------
    matrices : sequence of array_like of shape (D, D)
        All elements of the group (the identity included), each orthogonal
        (``g^T g = I`` to ``1e-12``), distinct, closed under products.  Checked
        here; ``ValueError`` otherwise.  :meth:`from_signs` builds diagonal
        ones from sign patterns.
    """

    matrices: tuple

    def __post_init__(self):
        try:
            mats = np.array([np.asarray(g, dtype=float) for g in self.matrices])
        except (TypeError, ValueError):
            raise ValueError(
                f"symmetry: the group elements must be square numeric matrices of one size, got {self.matrices!r}"
            ) from None
        if mats.ndim != 3 or len(mats) == 0 or mats.shape[1] != mats.shape[2] or mats.shape[1] == 0:
            raise ValueError(
                f"symmetry: the group elements must be square matrices (D, D) of one size, "
                f"got an array of shape {mats.shape}"
            )
        if not np.all(np.isfinite(mats)):
            raise ValueError("symmetry: the group elements must be finite")
        dim = mats.shape[1]
        eye = np.eye(dim)
        bad = [i for i, g in enumerate(mats) if np.abs(g.T @ g - eye).max() > _GROUP_TOL]
        if bad:
            raise ValueError(
                f"symmetry: element(s) {bad} are not orthogonal (g^T g != I): the group-averaged "
                "radial kernel needs orthogonal maps (|g x - g y| = |x - y|)"
            )

        def find(h):
            hits = np.flatnonzero(np.abs(mats - h).reshape(len(mats), -1).max(axis=1) <= _GROUP_TOL)
            return hits[0] if hits.size else -1

        if len({find(g) for g in mats}) != len(mats):
            raise ValueError("symmetry: the group elements must be distinct")
        if find(eye) < 0:
            raise ValueError("symmetry: not a group: the identity is missing (list every element of the group)")
        for i, g in enumerate(mats):
            for j, h in enumerate(mats):
                if find(g @ h) < 0:
                    raise ValueError(
                        f"symmetry: not a group: the product of elements {i} and {j} is not in the "
                        "list (list every element of the group, closed under products)"
                    )
        # rounded to the exact group elements (entries within 1e-12 of them)
        object.__setattr__(self, "matrices", tuple(tuple(tuple(float(v) for v in row) for row in g) for g in mats))
        object.__setattr__(self, "_mats", mats)

    @classmethod
    def from_signs(cls, patterns) -> "StateSymmetry":
        """The group of the diagonal matrices ``diag(s)`` for sign patterns ``s`` (entries +1 or -1).

        E.g. ``[(1, 1), (-1, -1), (1, -1), (-1, 1)]``: the Klein four-group of
        the sign flips of ``(q, p)`` (the pendulum's symmetries).
        """
        try:
            arr = np.array(patterns, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(
                f"symmetry: sign patterns must be sequences of +1/-1 of one length, got {patterns!r}"
            ) from None
        if arr.ndim != 2 or not np.all(np.abs(arr) == 1):
            raise ValueError(f"symmetry: sign patterns must be sequences of +1/-1 of one length, got {patterns!r}")
        return cls(tuple(np.diag(s) for s in arr))

    @classmethod
    def coerce(cls, value) -> Optional["StateSymmetry"]:
        """``None``, a :class:`StateSymmetry`, sign patterns (a 2-D array of +-1) or matrices (3-D), as a group."""
        if value is None or isinstance(value, StateSymmetry):
            return value
        if isinstance(value, (str, bytes, dict)):
            raise ValueError(
                f"symmetry must be None, a StateSymmetry, sign patterns or a list of matrices, got {value!r}"
            )
        try:
            ndim = np.asarray(value, dtype=float).ndim
        except (TypeError, ValueError):
            raise ValueError(
                f"symmetry must be None, a StateSymmetry, sign patterns (n_elements, D) or matrices "
                f"(n_elements, D, D) of one size, got {value!r}"
            ) from None
        if ndim == 2:
            return cls.from_signs(value)
        if ndim == 3:
            return cls(tuple(value))
        raise ValueError(
            f"symmetry must be sign patterns (n_elements, D) or matrices (n_elements, D, D), got {value!r}"
        )

    def __eq__(self, other) -> bool:
        return isinstance(other, StateSymmetry) and self.matrices == other.matrices

    def __hash__(self) -> int:
        return hash(self.matrices)

    def __repr__(self) -> str:
        if np.all(self._mats == np.eye(self.dim) * np.einsum("gii->gi", self._mats)[:, None, :]):
            return f"StateSymmetry.from_signs({np.einsum('gii->gi', self._mats).astype(int).tolist()})"
        return f"StateSymmetry({np.round(self._mats, 15).tolist()})"

    @property
    def dim(self) -> int:
        return self._mats.shape[1]

    @property
    def order(self) -> int:
        """``|G|``."""
        return len(self._mats)

    @property
    def array(self) -> np.ndarray:
        """The elements as an array of shape ``(|G|, D, D)`` (a copy)."""
        return self._mats.copy()

    @property
    def spec(self) -> dict:
        return {"matrices": [[list(row) for row in g] for g in self.matrices]}

    @classmethod
    def from_spec(cls, spec) -> Optional["StateSymmetry"]:
        """Rebuild from :attr:`spec` (``None`` stays ``None``); ``ValueError`` for a malformed one (re-checked)."""
        if spec is None:
            return None
        if not isinstance(spec, dict) or set(spec) != {"matrices"} or not isinstance(spec["matrices"], list):
            raise ValueError(f"malformed state-symmetry spec {spec!r}")
        return cls(tuple(spec["matrices"]))

    def check_dim(self, dim: int) -> None:
        """``ValueError`` unless the matrices act on states of dimension ``dim``."""
        if self.dim != dim:
            raise ValueError(
                f"symmetry: the group's matrices are {self.dim} x {self.dim}, the states have dimension {dim}"
            )

    def check_periodic(self, periodic: "PeriodicCoordinates") -> None:
        """``ValueError`` unless every element is a signed permutation mapping each periodic coordinate to one of
        the same period (and the others among themselves): then ``k_P(g x, g y) = k_P(x, y)`` for the periodic
        distance (``sin^2`` is even), and the group-averaged periodic kernel is invariant and periodic."""
        periodic.check_dim(self.dim)
        period = np.zeros(self.dim)
        period[list(periodic.coordinates)] = periodic.periods
        for i, g in enumerate(self._mats):
            nonzero = np.abs(g) > _GROUP_TOL
            signed_perm = np.all(nonzero.sum(axis=0) == 1) and np.all(np.abs(np.abs(g[nonzero]) - 1) <= _GROUP_TOL)
            rows, cols = np.nonzero(nonzero)
            if not signed_perm or np.any(np.abs(period[rows] - period[cols]) > 1e-12 * np.maximum(period[rows], 1)):
                raise ValueError(
                    f"symmetry: element {i} does not map the periodic coordinates {periodic.coordinates} "
                    "(periods " + f"{periodic.periods}) onto coordinates of the same period: a kernel both "
                    "Periodic and Symmetric needs signed permutations that respect the periods"
                )

    def conjugated(self, scale: np.ndarray) -> "StateSymmetry":
        """The group in the coordinates ``x~ = diag(scale) x``: ``diag(scale) g diag(scale)^-1``.

        ``ValueError`` where such a map is not orthogonal (the scaling does not commute with the group).
        """
        scale = np.asarray(scale, dtype=float)
        mats = scale[None, :, None] * self._mats / scale[None, None, :]
        try:
            return StateSymmetry(tuple(mats))
        except ValueError:
            raise ValueError(
                "symmetry: the group is not orthogonal in the scaled coordinates (state_scaling does "
                "not commute with it); use state_scaling=None or sign flips"
            ) from None

    def terms(self, y: np.ndarray, b: np.ndarray):
        """The plain HB functionals that make up ``d/dy_b`` of ``k_G`` at the points ``y``.

        ``d/dy_b k_G(., y) = sum_t w_t (d/dz_{c_t} k)(., z_t)`` with, for each
        group element ``g`` and component ``c`` with some ``g_cb != 0``:

        Parameters
        ----------
        y : ndarray of shape (K, D)
        b : ndarray of shape (K,), int

        Yields
        ------
        z : ndarray of shape (K, D)
            The images ``g y``.
        c : int
            The plain functional's component.
        w : ndarray of shape (K,)
            The weights ``g_{c b_k}`` (0 where that functional does not enter).

        Notes
        -----
        At most ``|G| D`` terms (``|G|`` for signed permutations), each ``O(K D)``.
        """
        b = np.asarray(b, dtype=np.int64)
        for g in self._mats:
            z = y @ g.T
            for c in range(self.dim):
                w = g[c, b]
                if np.any(w != 0.0):
                    yield z, c, w

    def expand(self, y: np.ndarray, b: np.ndarray):
        """:meth:`terms` flattened into plain functionals: ``(owner, z, c, w)``, zero weights dropped.

        Returns
        -------
        owner : ndarray of shape (T,), int64
            Index into ``y`` of each plain functional (sorted, stable).
        z : ndarray of shape (T, D)
        c : ndarray of shape (T,), int64
        w : ndarray of shape (T,)
        """
        y = np.asarray(y, dtype=float).reshape(-1, self.dim)
        b = np.asarray(b, dtype=np.int64).reshape(-1)
        owner, zs, cs, ws = [], [], [], []
        for z, c, w in self.terms(y, b):
            keep = np.flatnonzero(w != 0.0)
            owner.append(keep)
            zs.append(z[keep])
            cs.append(np.full(len(keep), c, dtype=np.int64))
            ws.append(w[keep])
        if not owner:  # no points
            return np.zeros(0, dtype=np.int64), np.zeros((0, self.dim)), np.zeros(0, dtype=np.int64), np.zeros(0)
        owner = np.concatenate(owner)
        order = np.argsort(owner, kind="stable")
        return owner[order], np.concatenate(zs)[order], np.concatenate(cs)[order], np.concatenate(ws)[order]

    def hb_diagonal(
        self, state: RadialKernel, x: np.ndarray, a: np.ndarray, periodic: Optional["PeriodicCoordinates"] = None
    ) -> np.ndarray:
        """Gramian diagonal ``d/dx_a d/dy_a k_G(x, y)`` at ``y = x`` (the parameter factors are 1 there).

        ``sum_t w_t (-B d_a d_c - A delta_ac)``, ``d = x - z_t`` (:meth:`terms`); with periodic
        coordinates ``d`` becomes ``G = g(d)`` and ``delta_ac`` is ``g'(d_a) delta_ac``
        (:meth:`PeriodicCoordinates.terms`).

        Parameters
        ----------
        x : ndarray of shape (K, D)
        a : ndarray of shape (K,), int

        Returns
        -------
        ndarray of shape (K,)
        """
        x = np.asarray(x, dtype=float)
        a = np.asarray(a, dtype=np.int64)
        rows = np.arange(len(x))
        out = np.zeros(len(x))
        for z, c, w in self.terms(x, a):
            d = x - z
            if periodic is None:
                r, g1 = np.sqrt(np.einsum("ka,ka->k", d, d)), None
            else:
                r, d, G1 = periodic.terms(d, order=2)
                g1 = G1[rows, a]
            A, B = state.factors(r, order=2)
            out += w * (-B * d[rows, a] * d[:, c] - (A if g1 is None else A * g1) * (a == c))
        return out


@dataclass(frozen=True)
class ProductKernel:
    """Product kernel ``k = k_xi(xi, xi') * k_mu(mu, mu') * k_dT(dT, dT')``.

    Derivatives are taken in the state block ``xi`` only, so every derivative
    of ``k`` is the corresponding derivative of ``k_xi`` times the parameter
    factor ``k_mu * k_dT`` (see :meth:`parameter_factor`).  A factor set to
    ``None`` is dropped (constant 1): a fixed parameter or a fixed step.
    ``periodic`` makes the state kernel periodic in some coordinates
    (:class:`PeriodicCoordinates`); ``symmetry`` makes it invariant under a
    finite orthogonal group (:class:`StateSymmetry`); ``None``: the plain
    radial kernel.  Both together: ``sum_g k_P(x, g y)`` with the periodic
    distance, for a group of signed permutations that maps each periodic
    coordinate to one of the same period (:meth:`StateSymmetry.check_periodic`).
    """

    state: RadialKernel
    mu: Optional[RadialKernel] = None
    dt: Optional[RadialKernel] = None
    periodic: Optional[PeriodicCoordinates] = None
    symmetry: Optional[StateSymmetry] = None

    def __post_init__(self):
        for name, k in (("state_kernel", self.state), ("mu_kernel", self.mu), ("dt_kernel", self.dt)):
            if k is None and name == "state_kernel":
                raise ValueError("state_kernel is required (IMQ, Matern32 or Matern52)")
            if k is not None and not isinstance(k, RadialKernel):
                raise ValueError(
                    f"{name} must be a sympredict.kernels kernel (IMQ, Matern32, Matern52) or None, got {k!r}"
                )
        if self.periodic is not None and not isinstance(self.periodic, PeriodicCoordinates):
            raise ValueError(f"periodic must be a PeriodicCoordinates or None, got {self.periodic!r}")
        if self.symmetry is not None and not isinstance(self.symmetry, StateSymmetry):
            raise ValueError(f"symmetry must be a StateSymmetry or None, got {self.symmetry!r}")
        if self.symmetry is not None and self.periodic is not None:
            self.symmetry.check_periodic(self.periodic)

    def parameter_factor(self, mu_a, dt_a, mu_b, dt_b) -> np.ndarray:
        """``k_mu(mu_a_i, mu_b_j) * k_dT(dt_a_i, dt_b_j)``.

        Parameters
        ----------
        mu_a : ndarray of shape (Na, d_mu)
        dt_a : ndarray of shape (Na,)
        mu_b : ndarray of shape (Nb, d_mu)
        dt_b : ndarray of shape (Nb,)
            ``d_mu`` may be 0; a dropped factor ignores its arguments.

        Returns
        -------
        ndarray of shape (Na, Nb)
        """
        out = None
        if self.mu is not None:
            out = self.mu(mu_a, mu_b)
        if self.dt is not None:
            kd = self.dt(dt_a, dt_b)
            out = kd if out is None else out * kd
        if out is None:
            out = np.ones((len(dt_a), len(dt_b)))
        return out

    @property
    def spec(self) -> dict:
        """``{'state', 'mu', 'dt'}`` kernel specs, and ``'periodic'``, ``'symmetry'`` only when set (older files lack them)."""
        spec = {
            "state": self.state.spec,
            "mu": None if self.mu is None else self.mu.spec,
            "dt": None if self.dt is None else self.dt.spec,
        }
        if self.periodic is not None:
            spec["periodic"] = self.periodic.spec
        if self.symmetry is not None:
            spec["symmetry"] = self.symmetry.spec
        return spec

    @classmethod
    def from_spec(cls, spec: dict) -> "ProductKernel":
        """Rebuild from :attr:`spec`; ``ValueError``/``KeyError`` for a malformed one."""
        return cls(
            kernel_from_spec(spec["state"]),
            kernel_from_spec(spec["mu"]),
            kernel_from_spec(spec["dt"]),
            PeriodicCoordinates.from_spec(spec.get("periodic")),
            StateSymmetry.from_spec(spec.get("symmetry")),
        )
