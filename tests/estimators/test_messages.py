"""Messages that name the fix: memory advice, close fixed steps, a normalized flow map's warnings in the user's units."""

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.exceptions import ExtrapolationWarning
from sympredict.kernels import IMQ
from sympredict.symplectic.solvers import NewtonSolver

DT = 0.1


def test_memory_advice_never_suggests_an_invalid_max_centers():
    from sympredict.interpolation.greedy.loop import check_memory

    with pytest.raises(ValueError) as info:
        check_memory(100, 10**6, 0, memory_limit=1000.0)
    assert "max_centers <= 0" not in str(info.value) and "memory_limit" in str(info.value)


def test_fixed_step_message_tells_two_close_steps_apart(coarse_pendulum_model, coarse_pendulum_data):
    other = DT + 1e-12
    with pytest.raises(ValueError) as info:
        coarse_pendulum_model.step(coarse_pendulum_data.x0[:1], dt=other)
    assert repr(DT) in str(info.value) and repr(other) in str(info.value)


def test_normalized_flow_map_warns_in_the_users_units():
    from sympredict.flowmap.scaling import BoxScaling, NormalizedFlowMap, SymplecticScaling

    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (40, 2))
    mu = rng.uniform(10.0, 20.0, 40)
    scaling = SymplecticScaling("none").fit(x)
    box = BoxScaling().fit(mu[:, None])
    inner = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), max_centers=10, solver=NewtonSolver(backend="numpy"))
    inner.fit(x, x + 0.01 * x[:, ::-1], mu=box.transform(mu[:, None]), dt=np.ones(40))
    flow = NormalizedFlowMap(inner, scaling, box, tau=0.25)
    with pytest.warns(ExtrapolationWarning) as caught:
        flow.step(x[:1] * 0.5, mu=30.0, dt=0.25)
    text = str(caught[0].message)
    assert "30.0" in text and "training steps 0.25..0.25" in text  # the user's mu and dt, not 2.0 and 1.0
