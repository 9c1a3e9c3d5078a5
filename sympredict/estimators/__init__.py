"""The estimators and their selection.

* :mod:`~sympredict.estimators.predictor`: :class:`~sympredict.SymplecticKernelPredictor`
  and the direct baseline :class:`~sympredict.DirectKernelPredictor` (both also
  in the package namespace);
* :mod:`~sympredict.estimators.auto`: :class:`~sympredict.KernelSearch`, how an
  estimator chooses the kernels, shapes and update it leaves open, and the fit's
  diagnostics;
* :mod:`~sympredict.estimators.selection`: kernel families, shapes and
  regularization chosen on validation data;
* :mod:`~sympredict.estimators.companion`: :class:`~sympredict.estimators.companion.CompanionEstimate`, an
  error estimate of a model's rollouts from a larger companion model.

Import from the modules; this package namespace imports nothing.
"""
