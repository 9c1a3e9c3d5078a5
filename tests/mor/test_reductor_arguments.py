"""The reductor checks its arguments (and its estimator's settings) before any FOM solve, and its messages tell
steps apart."""

import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.kernels import IMQ


@pytest.fixture(scope="module")
def wave_parts():
    pymordemos = pytest.importorskip("pymordemos.symplectic_wave_equation")
    from pymor.algorithms.symplectic import psd_complex_svd

    fom = pymordemos.discretize_fom(T=0.5)
    RB = psd_complex_svd(fom.solve(), 2)
    return fom, RB


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"dt": "0.1"}, r"dt must be a real number, got '0.1'"),
        ({"dt": [0.1, 0.2]}, r"dt must be a real number, got \[0.1, 0.2\]"),
        ({"dt": -0.1}, r"dt must be positive, got -0.1"),
        ({"n_samples": 0}, r"n_samples must be >= 2, got 0"),
        ({"n_samples": 2.5}, r"n_samples must be an integer"),
        ({"n_validation": 0}, r"n_validation must be >= 1, got 0"),
        ({"radius": -0.1}, r"radius must be >= 0, got -0.1"),
        ({"radius": "big"}, r"radius must be a real number"),
        ({"horizon": -1.0}, r"horizon must be positive, got -1.0"),
        ({"horizon": "1"}, r"horizon must be a real number"),
        ({"max_centers": 0}, r"max_centers must be >= 1, got 0"),
        ({"estimator": "imq"}, r"estimator must be an estimator"),
        ({"estimator": SymplecticKernelPredictor}, r"estimator must be an estimator"),
        ({"state": "log"}, r"TrainingScaling state must be one of"),
        ({"split": "A"}, r"split must be a QuadraticSplit \(e.g. split=QuadraticSplit\(A\)\) or None, got 'A'"),
        ({"samples": "reduced"}, r"samples must be GalerkinSamples\(...\), ProjectedTrajectories\(...\)"),
        ({"check_existence": "no"}, r"check_existence must be True or False"),
    ],
)
def test_reductor_checks_its_arguments_up_front(wave_parts, monkeypatch, kwargs, match):
    from sympredict.mor import SymplecticKernelReductor

    fom, RB = wave_parts
    monkeypatch.setattr(type(fom), "solve", lambda *a, **k: (_ for _ in ()).throw(AssertionError("FOM solved")))
    from sympredict.mor import DefaultEstimator, GalerkinSamples, TrainingScaling

    args = {"dt": 0.05, **kwargs}
    dt = args.pop("dt")
    sampling = {k: args.pop(k) for k in ("n_samples", "n_validation", "radius", "horizon") if k in args}
    samples = args.pop("samples", GalerkinSamples(**sampling))
    if "max_centers" in args:
        args["estimator"] = DefaultEstimator(args.pop("max_centers"))
    if "state" in args:
        args["scaling"] = TrainingScaling(args.pop("state"))
    with pytest.raises(ValueError, match=match):
        SymplecticKernelReductor(fom, RB, dt, samples, **args)


def test_reductor_checks_its_predictors_settings_before_sampling(monkeypatch):
    """A predictor with an unknown update, or without mu_kernel for varying parameters, was refused only after
    every FOM sample (in fit / reduce)."""
    pymordemos = pytest.importorskip("pymordemos.symplectic_wave_equation")
    from pymor.algorithms.symplectic import psd_complex_svd

    from sympredict.mor import GalerkinSamples, SymplecticKernelReductor

    from pymor.operators.block import BlockDiagonalOperator
    from pymor.operators.constructions import LincombOperator
    from pymor.parameters.functionals import ExpressionParameterFunctional

    demo = pymordemos.discretize_fom(T=0.5)  # its stiffness scaled by c^2 / 0.01, as in test_mor.py
    blocks = demo.H_op.blocks
    fom = demo.with_(
        H_op=BlockDiagonalOperator(
            [LincombOperator([blocks[0, 0]], [ExpressionParameterFunctional("c[0]**2/0.01", {"c": 1})]), blocks[1, 1]]
        )
    )
    RB = psd_complex_svd(fom.solve(fom.parameters.parse(0.1)), 2)
    train = fom.parameters.space(0.08, 0.12).sample_uniformly(2)
    monkeypatch.setattr(type(fom), "solve", lambda *a, **k: (_ for _ in ()).throw(AssertionError("FOM solved")))
    with pytest.raises(ValueError, match="update must be one of"):
        SymplecticKernelReductor(fom, RB, 0.05, GalerkinSamples(train), SymplecticKernelPredictor(update="leapfrog"))

    class NoChoice(SymplecticKernelPredictor):  # an estimator that does not choose an open mu_kernel itself
        _chooses_open_factors = False

    reductor = SymplecticKernelReductor(fom, RB, 0.05, GalerkinSamples(train), NoChoice(IMQ(1.0)))
    with pytest.raises(ValueError, match="mu_kernel=None"):
        reductor.reduce()


def test_reductor_refuses_a_parameter_space_of_other_parameters(wave_parts):
    from pymor.parameters.base import Parameters

    from sympredict.mor import GalerkinSamples, SymplecticKernelReductor

    fom, RB = wave_parts
    with pytest.raises(ValueError, match="parameter_space has the parameters"):
        SymplecticKernelReductor(fom, RB, 0.05, GalerkinSamples(parameter_space=Parameters({"k": 2}).space(0, 1)))
    with pytest.raises(ValueError, match="parameter_space must be a pyMOR ParameterSpace"):
        SymplecticKernelReductor(fom, RB, 0.05, GalerkinSamples(parameter_space=(0, 1)))


def test_projected_stride_message_tells_the_steps_apart(wave_parts):
    """dt a hair off a multiple of the FOM's output step: both printed with ``:.6g`` looked equal."""
    from sympredict.mor import ProjectedTrajectories, SymplecticKernelReductor

    fom, RB = wave_parts
    h = fom.T / fom.time_stepper.nt
    dt = 10 * h * (1 + 1e-8)
    with pytest.raises(ValueError, match="multiple of the FOM's output step") as info:
        SymplecticKernelReductor(fom, RB, dt, ProjectedTrajectories())
    assert repr(dt) in str(info.value) and repr(h) in str(info.value)
