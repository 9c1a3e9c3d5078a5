"""Unit invariance of the defaults: the same orbits in SI units and in units of order one give the same model.

A change of units ``q -> q / L``, ``t -> t / T`` (so ``p -> p T / L``, ``GM -> GM T^2 / L^3``, ``dT -> dT / T``)
maps the flow of one system onto the flow of the other; a choice that depended on the units would make the user's
choice of units a tuning knob.  The oracle: the defaults fitted to both give the same choice (the shapes related by
the units' conformal factor), the same centres, and predictions equal up to round-off.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.data import FlowMapData, TrajectoryData
from sympredict.estimators.search import pair_factors, state_weights
from sympredict.kernels.transforms import lower_state_kernel
from sympredict.systems.flowmaps import HamiltonianSystem

L_UNIT, GM_REF = 7.0e6, 4.0e14  # m, m^3/s^2
T_UNIT = float(np.sqrt(L_UNIT**3 / GM_REF))  # s
DT = 60.0  # s


def _kepler_h(x, mu):
    return 0.5 * (x[:, 2] ** 2 + x[:, 3] ** 2) - mu[:, 0] / np.hypot(x[:, 0], x[:, 1])


def _kepler_grad(x, mu):
    r3 = np.hypot(x[:, 0], x[:, 1]) ** 3
    return np.concatenate([mu[:, :1] * x[:, :2] / r3[:, None], x[:, 2:]], axis=1)


def _si(xc):
    """Canonical states (q / L, p T / L) in SI units."""
    return xc * np.array([L_UNIT, L_UNIT, L_UNIT / T_UNIT, L_UNIT / T_UNIT])


@pytest.fixture(scope="module")
def orbits():
    """Low Earth orbits (radius 6.8e6 to 7.4e6 m, eccentricity up to 0.05, GM in [3.6e14, 4.4e14] m^3/s^2),
    integrated in canonical units; ``(canonical TrajectoryData, SI TrajectoryData, test states, test GM)``."""
    rng = np.random.default_rng(3)
    system = HamiltonianSystem(_kepler_h, _kepler_grad, 4, parameters={"GM": 1}, rtol=1e-10)

    def draw(n):
        gm = rng.uniform(0.9, 1.1, n)
        r = rng.uniform(6.8e6, 7.4e6, n) / L_UNIT
        phase = rng.uniform(0, 2 * np.pi, n)
        speed = np.sqrt(gm / r) * rng.uniform(1.0, 1.05, n)  # circular to slightly eccentric
        q = r[:, None] * np.stack([np.cos(phase), np.sin(phase)], axis=1)
        p = speed[:, None] * np.stack([-np.sin(phase), np.cos(phase)], axis=1)
        return np.concatenate([q, p], axis=1), gm

    x0, gm = draw(30)
    states = system.trajectory(x0, gm[:, None], DT / T_UNIT, 10)
    canonical = TrajectoryData(states, gm, DT / T_UNIT)
    si = TrajectoryData(_si(states), gm * GM_REF, DT)
    xt, gt = draw(12)
    return canonical, si, xt, gt


def test_state_weights_are_the_symplectic_normalisation():
    # oracle: a_i = sqrt(std p_i / std q_i) from the states' columns, computed directly
    rng = np.random.default_rng(0)
    x0 = rng.normal(size=(400, 4)) * np.array([7e6, 2.0, 7e3, 0.5])
    x1 = x0 + rng.normal(size=x0.shape) * 1e-3 * np.array([7e6, 2.0, 7e3, 0.5])
    data = FlowMapData(x0, x1, None, np.full(len(x0), 60.0))
    x = np.vstack([x0, x1])
    a = np.sqrt(x[:, 2:].std(axis=0) / x[:, :2].std(axis=0))
    np.testing.assert_allclose(state_weights(data), np.concatenate([a, 1 / a]), rtol=1e-12)
    np.testing.assert_allclose(pair_factors(data), a, rtol=1e-12)
    # after the weighting, each pair's q and p spread alike
    w = x * state_weights(data)
    np.testing.assert_allclose(w[:, :2].std(axis=0), w[:, 2:].std(axis=0), rtol=1e-12)


@pytest.mark.paths
def test_the_defaults_choose_the_same_model_in_si_units_as_in_units_of_order_one(orbits):
    canonical, si, xt, gt = orbits
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mc = SymplecticKernelPredictor(max_centers=60).fit(canonical)
        ms = SymplecticKernelPredictor(max_centers=60).fit(si)
    # the same choice: update, family, symmetry; shapes related by the units
    assert ms.update_ == mc.update_
    kc, ks = lower_state_kernel(mc.choice_["state_kernel"]), lower_state_kernel(ms.choice_["state_kernel"])
    assert type(ks.radial) is type(kc.radial)
    assert ks.symmetry == kc.symmetry
    # the normalised coordinates differ by the conformal factor c = sqrt(T) / L: scaling factors a_i by sqrt(T),
    # the state shape by c, the parameter shape by GM_REF
    c = np.sqrt(T_UNIT) / L_UNIT
    np.testing.assert_allclose(np.asarray(kc.scaling) / np.asarray(ks.scaling), np.sqrt(T_UNIT), rtol=1e-9)
    assert ks.radial.eps == pytest.approx(kc.radial.eps * c, rel=1e-9)
    assert ms.choice_["mu_kernel"].eps == pytest.approx(mc.choice_["mu_kernel"].eps / GM_REF, rel=1e-9)
    assert ms.n_centers_ == mc.n_centers_
    # the same predictions, in SI units, up to round-off amplified by the fit (far below the model's error)
    step_c = _si(mc.step(xt, mu=gt, dt=DT / T_UNIT))
    step_s = ms.step(_si(xt), mu=gt * GM_REF, dt=DT)
    increment = np.linalg.norm((step_s - _si(xt)) * state_weights(FlowMapData(_si(xt), step_s, None, 60.0)), axis=1)
    miss = np.linalg.norm((step_s - step_c) * state_weights(FlowMapData(_si(xt), step_s, None, 60.0)), axis=1)
    assert np.all(miss <= 1e-8 * increment)
