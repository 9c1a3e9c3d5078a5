"""Hamiltonian systems: the pendulum (direct, low-dimensional case) and Hénon–Heiles.

The wave FOM (:mod:`sympredict.systems.wave`, imports pyMOR) and the quadratic
reduced systems (:mod:`sympredict.systems.quadratic`) are imported from their modules,
as are the model-agnostic flow-map data, samplers and existence checks the systems use
(:mod:`sympredict.systems.flowmaps`) and the exact flows of quadratic Hamiltonians
(:mod:`sympredict.systems.linear_flow`).
"""

from sympredict.systems.henon_heiles import HenonHeiles
from sympredict.systems.pendulum import Pendulum

__all__ = ["HenonHeiles", "Pendulum"]
