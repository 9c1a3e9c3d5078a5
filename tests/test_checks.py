"""One function per kind of input (sympredict._checks): each rule, and each message naming the argument, the value
(its shape or first offending entry) and the fix."""

import numpy as np
import pytest

from pathlib import Path

import sympredict
from sympredict._checks import (
    as_choice,
    as_flag,
    as_model_parameter,
    as_parameter,
    as_positive_int,
    as_real,
    as_real_array,
    as_states,
    as_steps,
    as_times,
    as_trajectories,
)
from sympredict.data import TrajectoryData


# ------------------------------------------------------------------ states (B, 2n) or (2n,)
def test_states_accepted_forms():
    x, single = as_states([0.1, 0.2], "x")
    assert single and x.shape == (1, 2) and x.flags.c_contiguous and x.dtype == float
    x, single = as_states(np.arange(8).reshape(2, 4), "x", dim=4)
    assert not single and x.shape == (2, 4)


@pytest.mark.parametrize(
    "value, kwargs, message",
    [
        (
            np.zeros((2, 3)),
            {},
            r"x must have an even, positive number of state components \(q, p\), shape \(batch, 2n\), "
            r"got shape \(2, 3\)",
        ),
        (np.zeros((2, 0)), {}, r"x must have an even, positive number of state components .* got shape \(2, 0\)"),
        (np.zeros((2, 4)), {"dim": 2}, r"x must have 2 state components \(2n = 2\), got 4"),
        (np.zeros((0, 2)), {}, r"x is empty \(shape \(0, 2\)\): give at least one state"),
        (np.zeros((2, 2, 2)), {}, r"x must have shape \(batch, 2n\) or \(2n,\), got \(2, 2, 2\)"),
        (np.zeros(2), {"allow_single": False}, r"x must have shape \(batch, 2n\), got \(2,\)"),
        (
            [[0.0, np.nan], [np.inf, 0.0]],
            {},
            r"x contains NaN or Inf \(index \(0, 1\): nan, 2 entries in all\): give finite",
        ),
        ([["a", "b"]], {}, r"x must be a real numeric array, got dtype <U1"),
        ([[1j, 0.0]], {}, r"x must be real, got complex values"),
        ([[0.0, 1.0], [2.0]], {}, r"x must be a numeric array"),
    ],
)
def test_states_messages(value, kwargs, message):
    with pytest.raises(ValueError, match=message):
        as_states(value, "x", **kwargs)


# ------------------------------------------------------------------ parameters mu (B, d_mu)
def test_parameters_accepted_forms():
    assert as_parameter(0.5, 3, 1).shape == (3, 1)
    assert as_parameter([1.0, 2.0, 3.0], 3, 1)[:, 0].tolist() == [1.0, 2.0, 3.0]
    assert as_parameter([1.0, 2.0], 3, 2).tolist() == [[1.0, 2.0]] * 3
    assert (
        as_parameter({"b": [2.0, 3.0], "a": 1.0}, 2, 3, parameters={"a": 1, "b": 2}).tolist() == [[1.0, 2.0, 3.0]] * 2
    )
    assert as_model_parameter(None, 4, 0).shape == (4, 0)


@pytest.mark.parametrize(
    "call, message",
    [
        (
            lambda: as_parameter([1.0, 2.0, 3.0], 2, 1),
            r"mu must have length 2 \(one value per instance\) or be a scalar, got \(3,\)",
        ),
        (lambda: as_parameter([1.0, 2.0, 3.0], 2, 2), r"mu must have 2 components per instance, got shape \(3,\)"),
        (lambda: as_parameter(np.ones((2, 3)), 2, 2), r"mu must have 2 component\(s\) \(as in training\), got 3"),
        (lambda: as_parameter(np.ones((3, 2)), 2, None), r"mu must have shape \(2, d_mu\), got \(3, 2\)"),
        (lambda: as_parameter([np.nan], 1, 1), r"mu contains NaN or Inf \(index 0: nan\)"),
        (
            lambda: as_parameter({"a": 1.0, "c": 2.0}, 1, 2, parameters={"a": 1, "b": 1}),
            r"mu has the parameter names \['a', 'c'\], the model's parameters are \{'a': 1, 'b': 1\}: give exactly these",
        ),
        (
            lambda: as_parameter({"a": 1.0, "b": 2.0}, 1, 2),
            r"mu is a dict with the keys \['a', 'b'\]: their order is ambiguous",
        ),
        (lambda: as_model_parameter(0.5, 1, 0), r"do not pass mu"),
        (lambda: as_model_parameter(None, 1, 2), r"mu is required: this model was trained with 2 parameter component"),
    ],
)
def test_parameter_messages(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# ------------------------------------------------------------------ steps dt, scalar or one per instance
def test_steps_accepted_forms():
    assert as_steps(0.1, 3).tolist() == [0.1] * 3
    assert as_steps([0.1], 2).tolist() == [0.1] * 2
    assert as_steps([0.1, 0.2], 2).tolist() == [0.1, 0.2]


@pytest.mark.parametrize(
    "value, message",
    [
        (None, r"dt is required: the macro time step, a positive float or one per instance"),
        ([-0.2, 0.0], r"dt must be positive, got min -0.2 \(index 0: -0.2, 2 entries in all\): give the macro time"),
        (0.0, r"dt must be positive, got min 0.0 \(index 0: 0.0"),
        ([0.1, 0.2, 0.3], r"dt must be a scalar or have shape \(2,\), got \(3,\)"),
        ([0.1, np.inf], r"dt contains NaN or Inf \(index 1: inf\)"),
    ],
)
def test_step_messages(value, message):
    with pytest.raises(ValueError, match=message):
        as_steps(value, 2)


# ------------------------------------------------------------------ trajectories (P, K+1, 2n) and their times
def test_trajectories_accepted_forms():
    assert as_trajectories(np.zeros((3, 5, 4))).shape == (3, 5, 4)
    assert as_trajectories(np.zeros((5, 4)), allow_single=True).shape == (1, 5, 4)
    assert as_times([0.0, 0.1, 0.3], 2, 3).shape == (2, 3)
    assert as_times([[0.0, 0.1], [1.0, 2.0]], 2, 2)[1].tolist() == [1.0, 2.0]


@pytest.mark.parametrize(
    "value, kwargs, message",
    [
        (
            np.zeros((2, 3, 3)),
            {},
            r"states must have shape \(P, K\+1, 2n\) with K >= 1 and an even 2n, got \(2, 3, 3\)",
        ),
        (np.zeros((2, 1, 2)), {}, r"states must have shape \(P, K\+1, 2n\) with K >= 1 .*got \(2, 1, 2\)"),
        (np.zeros((3, 2)), {}, r"got \(3, 2\)"),
        (np.zeros((3, 3)), {"allow_single": True}, r"\(or \(K\+1, 2n\) for one trajectory\), got \(1, 3, 3\)"),
        (np.zeros((1, 3, 2)), {"dim": 4}, r"states must have 4 state components \(2n = 4\), got 2"),
        (np.full((1, 3, 2), np.nan), {}, r"states contains NaN or Inf \(index \(0, 0, 0\): nan, 6 entries in all\)"),
    ],
)
def test_trajectory_messages(value, kwargs, message):
    with pytest.raises(ValueError, match=message):
        as_trajectories(value, **kwargs)


@pytest.mark.parametrize(
    "value, message",
    [
        ([0.0, 0.1], r"times must have shape \(P, K\+1\) = \(2, 3\) or \(K\+1,\) = \(3,\), got \(2,\)"),
        (
            [0.0, 0.2, 0.2],
            r"times must increase strictly along each trajectory: trajectory 0 has t\[1\] = 0.2 >= t\[2\] = 0.2 \(2 traj",
        ),
        ([[0.0, 0.1, 0.2], [0.0, 0.3, 0.1]], r"trajectory 1 has t\[1\] = 0.3 >= t\[2\] = 0.1$"),
        ([0.0, np.nan, 0.2], r"times contains NaN or Inf \(index 1: nan\)"),
    ],
)
def test_time_messages(value, message):
    with pytest.raises(ValueError, match=message):
        as_times(value, 2, 3)


def test_trajectory_data_uses_the_trajectory_rules():
    """TrajectoryData, the trajectory files and the reductor's given trajectories share these two functions."""
    with pytest.raises(ValueError, match=r"states must have shape \(P, K\+1, 2n\)"):
        TrajectoryData(np.zeros((2, 3, 3)), dt=0.1)
    with pytest.raises(ValueError, match=r"times must increase strictly"):
        TrajectoryData(np.zeros((1, 3, 2)), times=[0.0, 0.2, 0.1])
    data = TrajectoryData(np.zeros((2, 3, 2)), times=[0.0, 0.1, 0.2])
    assert data.times.shape == (2, 3) and data.dt == pytest.approx(0.1)


# ------------------------------------------------------------------ numbers and counts
@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: as_real("x", "h"), r"h must be a real number, got 'x'"),
        (lambda: as_real(True, "h"), r"h must be a real number, got True"),
        (lambda: as_real(np.nan, "h"), r"h must be finite, got nan"),
        (lambda: as_real(0.0, "h", positive=True), r"h must be positive, got 0.0"),
        (lambda: as_real(-1.0, "h", nonnegative=True), r"h must be >= 0, got -1.0"),
        (lambda: as_positive_int(2.5, "n"), r"n must be an integer >= 1, got 2.5"),
        (lambda: as_positive_int(-1, "n", minimum=0), r"n must be >= 0, got -1"),
        (lambda: as_real_array([1.0, np.inf], "a"), r"a contains NaN or Inf \(index 1: inf\): give finite numbers"),
        (lambda: as_real_array(np.nan, "a"), r"a contains NaN or Inf \(nan\)"),
    ],
)
def test_number_messages(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# ------------------------------------------------------------------ choices and flags
def test_choices_and_flags():
    assert as_choice("rk4", "scheme", ["rk4", "leapfrog"]) == "rk4"
    assert as_flag(np.True_, "lumped") is True and as_flag(False, "lumped") is False
    for call, message in [
        (lambda: as_choice("x", "scheme", ("a", "b")), r"scheme must be one of \('a', 'b'\), got 'x'"),
        (lambda: as_choice(["a"], "scheme", ("a",)), r"scheme must be one of \('a',\), got \['a'\]"),
        (lambda: as_flag("yes", "lumped"), r"lumped must be True or False, got 'yes'"),
        (lambda: as_flag(1, "lumped"), r"lumped must be True or False, got 1"),
    ]:
        with pytest.raises(ValueError, match=message):
            call()


# ------------------------------------------------------------------ each rule written once
@pytest.mark.parametrize(
    "rule",
    [
        "contains NaN or Inf",
        "(P, K+1, 2n) with K >= 1",
        "must increase strictly along",
        "must be True or False",
        "must be one of {choices}",
    ],
)
def test_each_rule_is_written_once(rule):
    """The message of a rule is written in sympredict/_checks.py only: every other module calls the function."""
    root = Path(sympredict.__file__).parent
    places = sorted(str(f.relative_to(root)) for f in root.rglob("*.py") if rule in f.read_text())
    allowed = {"_checks.py"} | ({"symplectic/solvers.py"} if rule == "must be True or False" else set())
    assert set(places) <= allowed and "_checks.py" in places, places


def test_swapped_callers_give_the_rules_messages(tmp_path):
    """Callers that swapped a local check for the one function: files (with the file named), systems, the CLI."""
    import argparse

    from sympredict.cli._options import _finite_float, _int_at_least
    from sympredict.io import read_trajectories
    from sympredict.mor.mass import MassMatrixCoordinates
    from sympredict.systems.henon_heiles import escape_energy

    np.savez(tmp_path / "t.npz", states=np.zeros((2, 3, 2)), times=[0.0, 0.2, 0.2])
    with pytest.raises(ValueError, match=r"t.npz.*times must increase strictly.*t\[1\] = 0.2 >= t\[2\] = 0.2"):
        read_trajectories(tmp_path / "t.npz")
    np.savez(tmp_path / "n.npz", states=np.zeros((1, 3, 2)) + [[[0.0, 0.0], [0.0, np.nan], [0.0, 0.0]]], dt=0.1)
    with pytest.raises(ValueError, match=r"n.npz.*key 'states' contains NaN or Inf \(index \(0, 1, 1\): nan\)"):
        read_trajectories(tmp_path / "n.npz")
    with pytest.raises(ValueError, match=r"lumped must be True or False, got 'no'"):
        MassMatrixCoordinates(np.eye(2), lumped="no")
    with pytest.raises(ValueError, match=r"lam must be finite, got inf"):
        escape_energy(np.inf)
    for parse, text, message in [
        (_finite_float(positive=True), "-0.5", "must be positive, got -0.5"),
        (_finite_float(), "nan", "must be finite, got nan"),
        (_int_at_least(2), "1", "must be >= 2, got 1"),
    ]:
        with pytest.raises(argparse.ArgumentTypeError, match=f"^{message}$"):
            parse(text)
