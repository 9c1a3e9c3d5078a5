"""Symplectic model order reduction on pyMOR.

* :mod:`~sympredict.mor.reductor`: :class:`SymplecticKernelReductor` and its ROM
  :class:`SymplecticKernelModel` (pyMOR's ``fom -> reduce() -> rom -> reconstruct()`` triad
  with a learned reduced flow map);
* :mod:`~sympredict.mor.samples`: where its samples come from (Galerkin flow, projected or given
  trajectories, given samples); :mod:`~sympredict.mor.existence`: the check that the generating function
  exists at ``dt``; :mod:`~sympredict.mor.selection`: kernels and ridge term chosen on validation data, the
  default estimator; :mod:`~sympredict.mor.parts`: the training coordinates and the split;
* :mod:`~sympredict.mor.basis`: complex-SVD symplectic bases, projection,
  reconstruction, the Galerkin ROM of quadratic Hamiltonians;
* :mod:`~sympredict.mor.nonlinear`: Galerkin and DEIM ROMs of the nonlinear
  (sine-Gordon) FOM.
"""

from sympredict.mor.parts import QuadraticSplit, TrainingScaling
from sympredict.mor.reductor import (
    SymplecticKernelModel,
    SymplecticKernelReductor,
    basis_matrix,
    check_symplectic_basis,
)
from sympredict.mor.samples import GalerkinSamples, GivenSamples, GivenTrajectories, ProjectedTrajectories
from sympredict.mor.selection import DefaultEstimator, ValidationSelection

__all__ = [
    "SymplecticKernelReductor",
    "SymplecticKernelModel",
    "check_symplectic_basis",
    "basis_matrix",
    "GalerkinSamples",
    "ProjectedTrajectories",
    "GivenTrajectories",
    "GivenSamples",
    "ValidationSelection",
    "DefaultEstimator",
    "QuadraticSplit",
    "TrainingScaling",
]
