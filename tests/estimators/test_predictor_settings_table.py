"""The estimators' settings as data: one table of constraints (``_parameter_constraints``) that ``check_params``
reads for ``fit``, model files and the reductor; each message names the setting, the value and the fix."""

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict._checks import Constraint, as_even_dimension, as_positive_int, check_settings
from sympredict.exceptions import ModelFileError
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.kernels.transforms import Periodic


@pytest.mark.parametrize("cls", [SymplecticKernelPredictor, DirectKernelPredictor])
def test_every_setting_has_one_row(cls):
    assert set(cls._parameter_constraints) == set(cls().get_params(deep=False))


BAD = [  # (setting, value, what the message must name as the fix)
    ("max_centers", 0, "max_centers"),
    ("max_centers", 2.5, "max_centers"),
    ("mu_kernel", "imq", "IMQ, Matern32, Matern52"),
    ("dt_kernel", Periodic(IMQ(1.0), coordinates=(0,)), "IMQ, Matern32, Matern52"),
    ("state_kernel", 0.5, "Scaled, Periodic, Symmetric"),
    ("trainer", "exact", "ExactGreedy()"),
    ("solver", "numba", "NewtonSolver(backend='numba')"),
    ("search", {"m_star": 10}, "KernelSearch(m_star=500)"),
    ("update", "leapfrog", "symplectic_euler"),
]


@pytest.mark.parametrize("name, value, fix", BAD, ids=[f"{b[0]}={b[1]!r}" for b in BAD])
def test_each_message_names_the_setting_the_value_and_the_fix(name, value, fix):
    """set_params refuses the value at once and changes nothing (scikit-learn's check_set_params); the same value
    set by attribute assignment is refused by fit's check with the same message."""
    est = SymplecticKernelPredictor(IMQ(0.3), trainer=ExactGreedy(tol=1e-9))
    before = est.get_params(deep=False)
    with pytest.raises(ValueError) as refused:
        valid = {"mu_kernel": IMQ(1.0)} if name == "max_centers" else {"max_centers": 7}
        est.set_params(**valid, **{name: value})  # a valid value given with it is not stored either
    after = est.get_params(deep=False)
    assert after.keys() == before.keys() and all(after[k] is before[k] for k in before), (before, after)
    setattr(est, name, value)
    with pytest.raises(ValueError) as info:
        est.check_params()
    assert str(refused.value) == str(info.value)
    for message in (str(refused.value), str(info.value)):
        assert name.split("_")[0] in message and fix in message, message
        if not isinstance(value, (int, float)) or name != "max_centers":
            assert repr(value) in message or str(value) in message, message


def test_the_direct_model_has_its_own_state_kernel_row():
    with pytest.raises(ValueError, match=r"state_kernel must be a radial state kernel .* got Periodic"):
        DirectKernelPredictor(Periodic(IMQ(1.0), coordinates=(0,))).check_params()
    assert DirectKernelPredictor(IMQ(1.0)).check_params() is not None


def test_model_files_are_checked_by_the_same_table(coarse_pendulum_model_file, tmp_path):
    """A file whose settings break a row is refused with that row's message (files are hostile input)."""
    from _model_files import _param, _rewrite  # tests/

    bad = _rewrite(coarse_pendulum_model_file, tmp_path / "bad.h5", settings=_param("max_centers", 0))
    with pytest.raises(ModelFileError, match="max_centers"):
        SymplecticKernelPredictor.load(bad)


def test_constraint_rows():
    row = Constraint(int, expected="an integer such as 3", check=lambda v, name: as_positive_int(v, name))
    assert row.validate("n", None) is None and row.validate("n", 3) == 3
    with pytest.raises(ValueError, match=r"n must be an integer such as 3, got 'x'"):
        row.validate("n", "x")
    with pytest.raises(ValueError, match="n"):
        row.validate("n", -1)
    with pytest.raises(ValueError, match="must be"):
        Constraint(int, expected="given", required=True).validate("n", None)

    class Owner:
        a, b = 2, None

    assert check_settings(Owner(), {"a": row, "b": row}) == {"a": 2, "b": None}


def test_the_even_dimension_rule_is_written_once():
    assert as_even_dimension(4) == 4
    with pytest.raises(ValueError, match="states must have an even dimension 2n"):
        as_even_dimension(3)
    with pytest.raises(ValueError, match="even"):  # the data's check (as_states) says it first
        SymplecticKernelPredictor(IMQ(0.3)).fit(np.zeros((4, 3)), np.ones((4, 3)), dt=0.1)
