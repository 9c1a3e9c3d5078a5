"""What the defaults say about the data: scales per coordinate and component, wrapped angles, one warning per
fit, an interrupted fit, noisy data, pre-release options beside their parts."""

import numpy as np
import pytest

from sympredict.data import TrajectoryData


# --------------------------------------------------------------------------- scales per coordinate and component
def _two_oscillators(amp2: float, p=30, k=10, dt=0.1, seed=0):
    rng = np.random.default_rng(seed)
    w, amp = np.array([1.0, 1.3]), np.array([1.0, amp2])
    ph, r = rng.uniform(0, 2 * np.pi, (p, 2)), rng.uniform(0.5, 1.0, (p, 2)) * amp
    t = np.arange(k + 1) * dt
    q = r[:, None, :] * np.cos(w * t[:, None] + ph[:, None, :])
    pp = -r[:, None, :] * w * np.sin(w * t[:, None] + ph[:, None, :])
    return TrajectoryData(np.concatenate([q, pp], axis=2), None, dt)


def test_pairs_of_very_different_scales_warn_and_the_diagnostics_name_the_coordinate():
    """Amplitudes 1 and 1e-6: a ScaleWarning names (q2, p2); the per-coordinate hold-out error and the advice too."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.exceptions import ScaleWarning

    with pytest.warns(ScaleWarning, match=r"\(q2, p2\) spread"):
        model = SymplecticKernelPredictor().fit(_two_oscillators(1e-6))
    err = model.diagnostics_.holdout_coordinate_error
    assert err.shape == (4,) and err[1] > 1e3 * err[0] and err[3] > 1e3 * err[2]
    assert any("q2" in a and "p2" in a and "learned badly" in a for a in model.diagnostics_.advice)


def test_pairs_of_similar_scales_do_not_warn():
    import warnings

    from sympredict import SymplecticKernelPredictor
    from sympredict.exceptions import ScaleWarning

    with warnings.catch_warnings():
        warnings.simplefilter("error", ScaleWarning)
        model = SymplecticKernelPredictor().fit(_two_oscillators(0.5))
    assert not any("learned badly" in a for a in model.diagnostics_.advice)
    assert np.all(np.isfinite(model.diagnostics_.holdout_coordinate_error))


def test_parameter_components_of_very_different_widths_warn_naming_the_narrow_one():
    from sympredict.estimators.auto import _warn_unbalanced_parameters
    from sympredict.data import FlowMapData
    from sympredict.exceptions import ScaleWarning

    rng = np.random.default_rng(0)
    mu = np.column_stack([rng.uniform(1, 2, 50), rng.uniform(0, 1e6, 50)])
    data = FlowMapData(rng.normal(size=(50, 2)), rng.normal(size=(50, 2)), mu, 0.1)
    with pytest.warns(ScaleWarning, match=r"mu1 \(width"):
        _warn_unbalanced_parameters(data)


# --------------------------------------------------------------------------- wrapped angles, one warning per fit
def _wrapped_pendulum():
    from sympredict.systems.pendulum import Pendulum

    x0 = np.column_stack([np.zeros(8), np.linspace(4.5, 5.5, 8)])  # rotating
    states = Pendulum().trajectory(x0, np.full(8, 0.75), 0.05, 30)
    states[..., 0] = (states[..., 0] + np.pi) % (2 * np.pi) - np.pi
    return TrajectoryData(states, None, 0.05)


def test_wrapped_angles_name_the_coordinate_and_periodic_once_per_fit():
    import warnings

    from sympredict import SymplecticKernelPredictor
    from sympredict.exceptions import UnderfitWarning, WrappedAngleWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        SymplecticKernelPredictor().fit(_wrapped_pendulum())
    wrapped = [w for w in caught if issubclass(w.category, WrappedAngleWarning)]
    assert len(wrapped) == 1 and "state coordinate 0 (q1)" in str(wrapped[0].message)
    assert "Periodic(None, coordinates=(0,))" in str(wrapped[0].message) and "unwrap" in str(wrapped[0].message)
    assert sum(issubclass(w.category, UnderfitWarning) for w in caught) <= 1  # about the final model only


def test_unwrapped_angles_do_not_warn():
    from sympredict.data import FlowMapData
    from sympredict.estimators.structure import warn_wrapped_angles

    data = _wrapped_pendulum()
    data.states[..., 0] = np.unwrap(data.states[..., 0], axis=1)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_wrapped_angles(data.pairs())
        warn_wrapped_angles(FlowMapData(np.zeros((3, 2)), np.ones((3, 2)), None, 0.1))


def test_candidate_underfits_are_not_warned_only_the_final_model():
    """A search whose candidates underfit: at most one UnderfitWarning, and it is about the final model."""
    import warnings

    from sympredict import SymplecticKernelPredictor
    from sympredict.exceptions import UnderfitWarning

    data = _wrapped_pendulum()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = SymplecticKernelPredictor().fit(data)
    under = [w for w in caught if issubclass(w.category, UnderfitWarning)]
    assert len(under) <= 1
    if under:
        assert f"{model.n_centers_} centre" in str(under[0].message) or "no centre" in str(under[0].message)


# --------------------------------------------------------------------------- fit interrupted at the end
def test_ctrl_c_at_the_end_of_fit_leaves_no_previous_diagnostics(monkeypatch):
    from sympredict import SymplecticKernelPredictor
    from sympredict.estimators import predictor as predictor_module

    model = SymplecticKernelPredictor(max_centers=30).fit(_two_oscillators(0.5, p=10))
    assert model.diagnostics_ is not None

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(predictor_module, "diagnose", interrupted)
    with pytest.raises(KeyboardInterrupt):
        model.fit(_two_oscillators(0.5, p=10, seed=1))
    assert "diagnostics_" not in model.__dict__ and "choice_" not in model.__dict__


# --------------------------------------------------------------------------- an old option and its new part both given
def test_old_option_and_new_part_both_given_cannot_silently_disagree():
    """The flat option is not a parameter any more: given beside the part that owns its setting, the call is
    refused (neither silently wins)."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.kernels import IMQ
    from sympredict.kernels.transforms import Periodic
    from sympredict.symplectic.solvers import NewtonSolver

    with pytest.raises(TypeError, match="newton_max_iter"):
        SymplecticKernelPredictor(solver=NewtonSolver(max_iter=100), newton_max_iter=3)
    with pytest.raises(TypeError, match="periodic"):
        SymplecticKernelPredictor(state_kernel=Periodic(IMQ(1.0), coordinates=(0,)), periodic=(1,))
    with pytest.raises(ValueError, match="no parameter 'newton_max_iter'"):
        SymplecticKernelPredictor().set_params(solver=NewtonSolver(max_iter=100), newton_max_iter=3)


# --------------------------------------------------------------------------- noisy data
def test_noisy_data_get_regularization_advice():
    from sympredict import SymplecticKernelPredictor
    from sympredict.systems.pendulum import Pendulum

    rng = np.random.default_rng(0)
    x0 = np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-1, 1, 30)])
    clean = Pendulum().trajectory(x0, np.full(30, 0.75), 0.05, 20)
    noisy = SymplecticKernelPredictor(max_centers=120).fit(
        TrajectoryData(clean + 1e-3 * rng.normal(size=clean.shape), None, 0.05)
    )
    assert any("noisy data?" in a and "regularization" in a for a in noisy.diagnostics_.advice)
    exact = SymplecticKernelPredictor(max_centers=120).fit(TrajectoryData(clean, None, 0.05))
    assert not any("noisy data?" in a for a in exact.diagnostics_.advice)
