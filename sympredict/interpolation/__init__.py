"""Generalized kernel interpolation: candidate functionals, fitted surrogates and the greedy.

* :mod:`~sympredict.interpolation.functionals`: candidate functionals (HB
  derivatives, point values), Gramian columns, direct residual evaluation;
* :mod:`~sympredict.interpolation.surrogate`: the fitted expansions (the
  generating function ``s`` and the direct model's vector field);
* :mod:`~sympredict.interpolation.greedy`: the one greedy loop, its stores and
  the training strategies.

Import from the modules; this package namespace imports nothing.
"""
