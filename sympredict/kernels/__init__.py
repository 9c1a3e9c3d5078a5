"""Kernels: the radial families (one class each, formulas shared by NumPy and numba) and the product kernel.

* :mod:`~sympredict.kernels.radial`: :class:`RadialKernel` and its families
  (:class:`IMQ`, :class:`Matern52`, :class:`Matern32`), the registry
  (:data:`KERNEL_FAMILIES`, :func:`register_family`, :func:`kernel_from_spec`),
  the state-kernel modifications (:class:`PeriodicCoordinates`,
  :class:`StateSymmetry`) and the :class:`ProductKernel` on ``(xi, mu, dT)``.

The compiled kernels built from the families' formulas are :mod:`sympredict.kernels._compiled`.
"""

from sympredict.kernels.radial import (
    IMQ,
    KERNEL_FAMILIES,
    Matern32,
    Matern52,
    PeriodicCoordinates,
    ProductKernel,
    RadialKernel,
    StateSymmetry,
    kernel_from_spec,
    pairwise_distances,
    register_family,
)

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
