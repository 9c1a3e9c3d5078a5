"""Hamiltonian systems: the pendulum (direct, low-dimensional case) and Hénon–Heiles.

The wave FOM (:mod:`sympredict.systems.wave`, imports pyMOR) and the quadratic
reduced systems (:mod:`sympredict.systems.quadratic`) are imported from their modules.
"""

from sympredict.systems.henon_heiles import HenonHeiles
from sympredict.systems.pendulum import Pendulum

__all__ = ["HenonHeiles", "Pendulum"]
