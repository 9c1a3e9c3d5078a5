"""Kernels: the radial families (one class each, formulas shared by NumPy and numba) and the product kernel.

* :mod:`~sympredict.kernels.radial`: :class:`RadialKernel` and its families
  (:class:`IMQ`, :class:`Matern52`, :class:`Matern32`), the registry
  (:data:`KERNEL_FAMILIES`, :func:`register_family`, :func:`kernel_from_spec`),
  the state-kernel modifications (:class:`PeriodicCoordinates`,
  :class:`StateSymmetry`) and the :class:`ProductKernel` on ``(xi, mu, dT)``.

The compiled kernels built from the families' formulas are :mod:`sympredict.kernels._compiled`.
"""

from sympredict.kernels import radial
from sympredict.kernels.radial import *  # noqa: F403 - the package's names are the radial module's (its __all__)

__all__ = list(radial.__all__)
