"""Symplectic steps: the Newton solvers of the learned implicit step, classical integrators, error measures.

* :mod:`~sympredict.symplectic.newton`: Newton solvers of the implicit steps
  (NumPy references and the compiled rollout, whose numba code is
  :mod:`~sympredict.symplectic._compiled_newton`);
* :mod:`~sympredict.symplectic.integrators` and
  :mod:`~sympredict.symplectic.integrators_compiled`: classical symplectic
  schemes (references and baselines), NumPy and compiled;
* :mod:`~sympredict.symplectic.metrics`: trajectory and Hamiltonian errors,
  symplecticity defect, ``J``.

Import from the modules; this package namespace imports nothing.
"""
