"""Symplectic model order reduction on pyMOR.

* :mod:`~sympredict.mor.reductor`: :class:`SymplecticKernelReductor` and its ROM
  :class:`SymplecticKernelModel` (pyMOR's ``fom -> reduce() -> rom -> reconstruct()`` triad
  with a learned reduced flow map);
* :mod:`~sympredict.mor.basis`: complex-SVD symplectic bases, projection,
  reconstruction, the Galerkin ROM of quadratic Hamiltonians;
* :mod:`~sympredict.mor.nonlinear`: Galerkin and DEIM ROMs of the nonlinear
  (sine-Gordon) FOM.
"""

from sympredict.mor.reductor import SymplecticKernelModel, SymplecticKernelReductor, basis_matrix, check_symplectic_basis

__all__ = ["SymplecticKernelReductor", "SymplecticKernelModel", "check_symplectic_basis", "basis_matrix"]
