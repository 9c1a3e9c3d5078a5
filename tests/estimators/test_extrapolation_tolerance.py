"""The extrapolation warning's tolerance: silent on orbits drawn like the training ones, precise on those that leave.

Oracle: the box of the training states and the excess of each predicted state over it, computed here from the
returned trajectories (``EXTRAPOLATION_TOLERANCE`` of the box's width per coordinate).
"""

import re
import warnings

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.estimators.predictor import EXTRAPOLATION_TOLERANCE
from sympredict.exceptions import ExtrapolationWarning
from sympredict.kernels import IMQ
from sympredict.kernels.transforms import Scaled
from sympredict.systems.three_body import MU_RANGE, ThreeBody, librating_states

DT = 0.05


@pytest.fixture(scope="module")
def three_body():
    """60 tadpole trajectories of 60 steps near L4 (mass ratios in MU_RANGE) and a small midpoint model of them."""
    system = ThreeBody()
    rng = np.random.default_rng(0)
    mu = rng.uniform(*MU_RANGE, 60)
    traj = system.trajectory(librating_states(mu, 60, seed=0), mu, DT, 60)
    x0, x1 = traj[:, :-1].reshape(-1, 4), traj[:, 1:].reshape(-1, 4)
    model = SymplecticKernelPredictor(
        Scaled(IMQ(1.0), factors=(0.8, 1.25)), IMQ(5.0), max_centers=150, update="midpoint"
    ).fit(x0, x1, mu=np.repeat(mu, 60), dt=DT)
    return system, model, traj


def _excess(model, traj):
    lo, hi = model.domain_["x_min"], model.domain_["x_max"]
    return (np.maximum(np.maximum(lo - traj, traj - hi), 0.0) / (hi - lo)).max(axis=-1)


def test_orbits_drawn_like_the_training_ones_do_not_warn(three_body):
    """40 orbits from the training distribution (the same sampler and length): some overshoot the box a little
    (the exact box would flag them), none by the tolerance, and the rollout says nothing."""
    system, model, _ = three_body
    mu = np.random.default_rng(1).uniform(*MU_RANGE, 40)
    x = librating_states(mu, 40, seed=11)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtrapolationWarning)
        pred = model.rollout(x, 60, mu=mu)
    excess = _excess(model, pred).max(axis=1)
    assert excess.max() > 0  # at least one orbit leaves the exact box ...
    assert excess.max() <= EXTRAPOLATION_TOLERANCE  # ... by less than the tolerance


def test_orbits_that_leave_by_more_than_the_tolerance_are_named(three_body):
    """Longer orbits (400 steps: further round the libration than any training trajectory) leave the box; the
    warning names exactly those whose excess passes the tolerance, the coordinate that left farthest, and by
    how much."""
    system, model, _ = three_body
    mu = np.random.default_rng(2).uniform(*MU_RANGE, 8)
    x = librating_states(mu, 8, seed=12)
    with pytest.warns(ExtrapolationWarning) as caught:
        pred = model.rollout(x, 400, mu=mu)
    message = str(caught[0].message)
    excess = _excess(model, pred)
    left = np.flatnonzero((excess[:, 1:] > EXTRAPOLATION_TOLERANCE).any(axis=1))
    assert 0 < len(left) < 8  # some orbits leave, some stay within the tolerance
    assert f"{len(left)} of 8 trajectories leave the training states" in message
    assert f"by more than {100 * EXTRAPOLATION_TOLERANCE:g} % of the box's width" in message
    listed = [int(v) for v in re.search(r"instances \[([\d, ]+)\]", message).group(1).split(",")]
    assert listed == left[:5].tolist()
    # the coordinate that left farthest, and by how much
    flat = excess[left].reshape(-1, 4)
    lo, hi = model.domain_["x_min"], model.domain_["x_max"]
    rel = (np.maximum(np.maximum(lo - pred[left], pred[left] - hi), 0.0) / (hi - lo)).reshape(-1, 4)
    row, col = np.unravel_index(np.argmax(rel), rel.shape)
    assert flat.max() == pytest.approx(rel[row, col])
    match = re.search(
        r"state coordinate (\d) \((\w+)\) left the box \[\S+, \S+\] by (\S+) \(([\d.]+) % of its width\)", message
    )
    assert match and int(match.group(1)) == col
    assert float(match.group(4)) == pytest.approx(100 * rel[row, col], abs=0.06)
    value = pred[left].reshape(-1, 4)[row, col]
    assert float(match.group(3)) == pytest.approx(max(value - hi[col], lo[col] - value), rel=1e-2)


def test_a_query_state_outside_by_more_than_the_tolerance_warns_with_its_coordinate(three_body):
    _, model, _ = three_body
    lo, hi = model.domain_["x_min"], model.domain_["x_max"]
    inside = 0.5 * (lo + hi)
    near = inside.copy()
    near[1] = hi[1] + 0.5 * EXTRAPOLATION_TOLERANCE * (hi[1] - lo[1])  # within the tolerance: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtrapolationWarning)
        model.step(near, mu=0.012)
    far = inside.copy()
    far[2] = lo[2] - 3 * EXTRAPOLATION_TOLERANCE * (hi[2] - lo[2])
    with pytest.warns(
        ExtrapolationWarning,
        match=r"query states span .*state coordinate 2 \(p1\) left the box .* "
        r"\(15\.0 % of its width\)",
    ):
        model.step(far, mu=0.012)
