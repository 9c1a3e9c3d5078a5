"""Mass matrices that are not positive definite or badly conditioned, and reductor data outside the parameter space."""

import numpy as np
import pytest


# --------------------------------------------------------------------------- mass matrices
@pytest.mark.parametrize("lumped", [True, False])
def test_indefinite_mass_is_refused_also_lumped(lumped):
    from sympredict.mor.mass import MassMatrixCoordinates

    with pytest.raises(ValueError, match="not positive definite|non-positive"):
        MassMatrixCoordinates(np.array([[1.0, 2.0], [2.0, 1.0]]), lumped=lumped)  # row sums 3, eigenvalue -1
    with pytest.raises(ValueError, match="non-positive|not positive definite"):
        MassMatrixCoordinates(np.array([[-1.0, 3.0], [3.0, -1.0]]), lumped=lumped)  # negative masses


@pytest.mark.parametrize("lumped", [True, False])
def test_ill_conditioned_mass_is_refused(lumped):
    from sympredict.mor.mass import MassMatrixCoordinates

    with pytest.raises(ValueError, match="ill-conditioned"):
        MassMatrixCoordinates(np.diag([1.0, 1e-300]), lumped=lumped)
    MassMatrixCoordinates(np.diag([1.0, 1e-6]), lumped=lumped)


# --------------------------------------------------------------------------- reductor inputs
def test_reductor_trajectories_outside_parameter_space_are_refused(small_fe_wave):
    from sympredict.mor import GalerkinSamples, SymplecticKernelReductor

    fom, coords, space, train, RB = small_fe_wave
    far = fom.parameters.space(5.0, 6.0)
    with pytest.raises(ValueError, match="training_parameters: parameter .* lies outside parameter_space"):
        SymplecticKernelReductor(fom, RB, 0.01, GalerkinSamples(train, parameter_space=far))
