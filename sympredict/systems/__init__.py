"""Hamiltonian systems: the pendulum (direct, low-dimensional case)."""

from sympredict.systems.pendulum import Pendulum

__all__ = ["Pendulum"]
