"""Wrappers around a fitted flow-map predictor that keep its step symplectic.

* :mod:`~sympredict.flowmap.scaling`: parameter, step and (conformally)
  symplectic state scalings (:class:`~sympredict.flowmap.scaling.NormalizedFlowMap`);
* :mod:`~sympredict.flowmap.splitting`: the exact-linear-flow splitting
  ``L_h o S o L_h`` (:class:`~sympredict.flowmap.splitting.SplitKernelPredictor`);
* :mod:`~sympredict.flowmap.protocol`: what every flow map offers
  (:class:`~sympredict.flowmap.protocol.FlowMap`, ``SymplecticFlowMap``).

Import from the modules; this package namespace imports nothing.
"""
