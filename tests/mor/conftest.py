"""Fixtures of the reductor tests."""

import pytest


@pytest.fixture(scope="module")
def small_fe(small_fe_wave):
    """The small FE wave model's ``(fom, parameter space, training speeds, basis)`` (``tests/conftest.py``)."""
    fom, _, space, train, RB = small_fe_wave
    return fom, space, train, RB
