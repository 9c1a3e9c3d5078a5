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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

__all__ = ["RadialKernel", "IMQ", "Matern32", "Matern52", "ProductKernel", "KERNEL_FAMILIES", "kernel_from_spec"]

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


class RadialKernel:
    """Base class of radial kernels ``k(x, y) = phi(eps * |x - y|)``.

    Parameters
    ----------
    eps
        Shape parameter, a finite positive float.  Larger ``eps`` means a
        narrower kernel.
    """

    #: Short name used in files and specs.
    name: str = "radial"

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

    @property
    def spec(self) -> dict:
        """A JSON/HDF5-friendly description ``{'family': name, 'eps': eps}``."""
        return {"family": self.name, "eps": self.eps}

    # --- profile and derivative factors, all elementwise in ``r >= 0`` ---
    def phi(self, r: np.ndarray) -> np.ndarray:
        """Kernel profile ``phi(r)``, elementwise."""
        raise NotImplementedError

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
        raise NotImplementedError

    # --- matrix-valued helpers ---
    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Kernel matrix ``k(x_i, y_j)``.

        Parameters
        ----------
        x : ndarray of shape (Nx, d)
        y : ndarray of shape (Ny, d)

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


def _safe_inverse_r(r: np.ndarray):
    """Return ``(1/r, mask)`` with ``1/r`` replaced by 0 where ``r < _R_TINY``."""
    small = r < _R_TINY
    inv = 1.0 / np.where(small, 1.0, r)
    inv[small] = 0.0
    return inv, small


class IMQ(RadialKernel):
    """Inverse multiquadric ``phi(r) = (1 + eps^2 r^2)^(-1/2)`` (infinitely smooth)."""

    name = "imq"

    def phi(self, r):
        r = np.asarray(r, dtype=float)
        return 1.0 / np.sqrt(1.0 + (self.eps * r) ** 2)

    def factors(self, r, order=2):
        r = np.asarray(r, dtype=float)
        e2 = self.eps**2
        inv_u = 1.0 / (1.0 + e2 * r * r)
        sq = np.sqrt(inv_u)
        A = -e2 * inv_u * sq  # -e^2 u^(-3/2)
        B = 3.0 * e2 * e2 * inv_u * inv_u * sq  # 3 e^4 u^(-5/2)
        if order == 2:
            return A, B
        C = -15.0 * e2 * e2 * e2 * inv_u**3 * sq  # -15 e^6 u^(-7/2)
        return A, B, C


class Matern52(RadialKernel):
    """Matérn 5/2 ``phi(r) = (1 + eps r + eps^2 r^2 / 3) exp(-eps r)`` (``C^4``)."""

    name = "matern52"

    def phi(self, r):
        er = np.minimum(self.eps * np.asarray(r, dtype=float), _EXP_CLAMP)
        return (1.0 + er + er * er / 3.0) * np.exp(-er)

    def factors(self, r, order=2):
        r = np.asarray(r, dtype=float)
        e = self.eps
        er = np.minimum(e * r, _EXP_CLAMP)
        E = np.exp(-er)
        A = -(e * e / 3.0) * (1.0 + er) * E
        B = (e**4 / 3.0) * E
        if order == 2:
            return A, B
        inv_r, _ = _safe_inverse_r(r)
        C = -(e**5 / 3.0) * E * inv_r
        return A, B, C


class Matern32(RadialKernel):
    """Matérn 3/2 ``phi(r) = (1 + eps r) exp(-eps r)`` (``C^2`` only).

    Its surrogate Hessian (third kernel derivatives) is bounded but
    discontinuous at the centres; Newton still converges, at a lower rate
    when an iterate sits on a centre.
    """

    name = "matern32"

    def phi(self, r):
        er = np.minimum(self.eps * np.asarray(r, dtype=float), _EXP_CLAMP)
        return (1.0 + er) * np.exp(-er)

    def factors(self, r, order=2):
        r = np.asarray(r, dtype=float)
        e = self.eps
        er = np.minimum(e * r, _EXP_CLAMP)
        E = np.exp(-er)
        inv_r, _ = _safe_inverse_r(r)
        A = -e * e * E
        B = e**3 * E * inv_r
        if order == 2:
            return A, B
        C = -(e**3) * (1.0 + er) * E * inv_r**3
        return A, B, C


#: The kernel families by name (as used in specs, files and the CLI).
KERNEL_FAMILIES = {cls.name: cls for cls in (IMQ, Matern32, Matern52)}


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
class ProductKernel:
    """Product kernel ``k = k_xi(xi, xi') * k_mu(mu, mu') * k_dT(dT, dT')``.

    Derivatives are taken in the state block ``xi`` only, so every derivative
    of ``k`` is the corresponding derivative of ``k_xi`` times the parameter
    factor ``k_mu * k_dT`` (see :meth:`parameter_factor`).  A factor set to
    ``None`` is dropped (constant 1): a fixed parameter or a fixed step.
    """

    state: RadialKernel
    mu: Optional[RadialKernel] = None
    dt: Optional[RadialKernel] = None

    def __post_init__(self):
        for name, k in (("state_kernel", self.state), ("mu_kernel", self.mu), ("dt_kernel", self.dt)):
            if k is None and name == "state_kernel":
                raise ValueError("state_kernel is required (IMQ, Matern32 or Matern52)")
            if k is not None and not isinstance(k, RadialKernel):
                raise ValueError(
                    f"{name} must be a sympredict.kernels kernel (IMQ, Matern32, Matern52) or None, got {k!r}"
                )

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
        return {
            "state": self.state.spec,
            "mu": None if self.mu is None else self.mu.spec,
            "dt": None if self.dt is None else self.dt.spec,
        }
