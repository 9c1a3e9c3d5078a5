"""Issue 15, long-time and large-step pieces: the energy-boundedness criterion on synthetic series, the
training-pair augmentations (u -> -u, energy samples of the Galerkin ROM), the large-step rule, and the
symplectic inverse without a dense J."""

from dataclasses import replace

import numpy as np
import pytest

from sympredict_paper.sine_gordon import (
    PRESETS,
    EnergySamples,
    choose_large_step,
    energy_boundedness,
    no_augmentation,
    sign_symmetry,
)
from sympredict.symplectic.metrics import canonical_J
from sympredict.mor.basis import symplectic_inverse, symplecticity_of_basis

K = 50  # steps of the training horizon
t = np.arange(10 * K + 1) / K  # in units of T


def test_energy_boundedness_accepts_bounded_oscillations():
    rng = np.random.default_rng(0)
    # a symplectic map's energy error: an oscillation at a fixed level (plus a quasi-periodic part), from 0
    e = 1e-3 * np.abs(np.sin(7.0 * t)) * (1 + 0.3 * np.sin(1.3 * t)) + 1e-5 * rng.random(len(t))
    e[0] = 0.0
    r = energy_boundedness(e, K)
    assert r["all_bounded"] and r["ratio"][0] <= 3.0 and abs(r["rise"][0]) < 1.0
    # two series at once, one per row
    r2 = energy_boundedness(np.stack([e, 2 * e]), K)
    assert r2["bounded"] == [True, True] and np.isclose(r2["ratio"][1], r["ratio"][0])


def test_energy_boundedness_rejects_secular_growth():
    e = 1e-3 * np.abs(np.sin(7.0 * t)) * (1 + 0.5 * t)  # linear drift of the envelope
    r = energy_boundedness(e, K)
    assert not r["all_bounded"] and r["rise"][0] > 2.0 and r["ratio"][0] > 3.0
    # a steady ramp from well below the [0, T] level to just below 3 m0 (the max test alone passes) whose fitted
    # envelope rises by more than 2 m0: secular growth caught by the fit
    ramp = np.full(len(t), 1e-3)
    ramp[: K + 1] = 1e-3 * np.abs(np.sin(7.0 * t[: K + 1])) / np.abs(np.sin(7.0 * t[: K + 1])).max()
    ramp[K + 1 :] = 1e-3 * np.linspace(0.1, 2.95, len(t) - K - 1)
    r = energy_boundedness(ramp, K)
    assert r["ratio"][0] <= 3.0 and r["rise"][0] > 2.0 and not r["all_bounded"]
    # the same series with the scatter of a bounded quasi-periodic error around a flat level passes
    flat = ramp.copy()
    flat[K + 1 :] = 1e-3 * (1.5 + 0.9 * np.sin(0.37 * np.arange(len(t) - K - 1)))
    assert energy_boundedness(flat, K)["all_bounded"]


def test_energy_boundedness_rejects_jumps_blowups_and_nan():
    e = 1e-3 * np.abs(np.sin(7.0 * t))
    jump = e.copy()
    jump[6 * K :] *= 10  # bounded after the jump, but 10x the training level
    assert not energy_boundedness(jump, K)["all_bounded"]
    assert energy_boundedness(jump, K)["ratio"][0] > 3.0
    # below the floor (0.1 %) the level counts as conserved: a tiny error that grows 5x is still bounded, the same
    # shape at a higher level is not
    tiny = 1e-5 * np.abs(np.sin(7.0 * t)) * np.where(t > 1, 5.0, 1.0)
    assert energy_boundedness(tiny, K)["all_bounded"]
    assert not energy_boundedness(tiny * 1e3, K)["all_bounded"]
    assert not energy_boundedness(tiny, K, floor=0.0)["all_bounded"]
    blown = 5.0 + e  # already 500 % on [0, T]: not bounded, even though it is flat
    assert not energy_boundedness(blown, K)["all_bounded"]
    bad = e.copy()
    bad[-1] = np.nan
    assert energy_boundedness(np.stack([e, bad]), K)["bounded"] == [True, False]
    with pytest.raises(ValueError):
        energy_boundedness(e[: K + 1], K)  # nothing after T


@pytest.fixture(scope="module")
def small(small_sine_gordon):
    """(conftest.small_sine_gordon) a small FOM, a 2n = 6 basis from 4 trajectories, its Galerkin ROM."""
    return small_sine_gordon


def test_sign_symmetry_pairs_are_exact_samples(small):
    fom, gal, X, c = small
    Y = gal.project(X)
    x0, x1, mu = sign_symmetry(Y[:, :-1], Y[:, 1:], c)
    assert x0.shape == (2 * 4 * 20, 6) and mu.shape == (160, 1)
    # u -> -u maps a FOM trajectory onto the trajectory from -x(0) (sin is odd): its projection is the image pair
    Xm = fom.reference_trajectory(-X[:, 0], c, 0.1, 20, tol=1e-8)
    Ym = gal.project(Xm)
    assert np.allclose(x0[80:], Ym[:, :-1].reshape(-1, 6), atol=1e-7)
    assert np.allclose(x1[80:], Ym[:, 1:].reshape(-1, 6), atol=1e-7)
    assert np.allclose(no_augmentation(Y[:, :-1], Y[:, 1:], c)[0], x0[:80])


@pytest.mark.parametrize("region", ["sublevel", "box"])
def test_energy_samples_stay_below_the_training_energy_and_are_galerkin_steps(small, region):
    fom, gal, X, c = small
    Yg = gal.solve(gal.project(X[:, 0]), c, 0.1, 20, substeps=4)
    aug = EnergySamples(gal, (0.8, 1.2), 0.1, substeps=4, n_per_pair=0.5, region=region, seed=3)
    x0, x1, mu = aug(Yg[:, :-1], Yg[:, 1:], c)
    m = 4 * 20
    assert len(x0) == m + 40 and np.allclose(x0[:m], Yg[:, :-1].reshape(-1, 6))
    y, y1, cc = x0[m:], x1[m:], mu[m:, 0]
    states = Yg.reshape(-1, 6)
    e_max = gal.reduced_energy(states, np.repeat(c, 21)).max()
    e = gal.reduced_energy(y, cc)
    assert np.all(e <= e_max * (1 + 1e-9)) and np.all((cc >= 0.8) & (cc <= 1.2))
    if region == "box":
        assert np.all((y >= states.min(axis=0)) & (y <= states.max(axis=0)))
    else:  # energy levels spread over (0, E_max], not only near it; many states outside the training box
        assert e.min() < 0.3 * e_max and e.max() > 0.7 * e_max
    # each sample is stepped by the Galerkin ROM over DT (its own solve, one state at a time)
    for i in (0, 17):
        ref = gal.solve(y[i], cc[i], 0.1, 1, substeps=4)[0, 1]
        assert np.allclose(y1[i], ref, atol=1e-12)
    # the Galerkin ROM conserves H, so the sampled pairs keep their energy (up to its step error)
    assert np.allclose(gal.reduced_energy(y1, cc), e, rtol=1e-3)
    with pytest.raises(ValueError):
        EnergySamples(gal, (0.8, 1.2), 0.1, region="ball")(Yg[:, :-1], Yg[:, 1:], c)


def test_choose_large_step_follows_the_training_rule(small):
    fom, gal, X, c = small
    p = replace(PRESETS["smoke"], large_step=3, large_step_candidates=(5, 10))
    ch = choose_large_step(p, gal, X, c, 20)
    table = {r["large_step"]: r for r in ch["table"]}
    assert set(table) == {3, 5, 10}
    for r in ch["table"]:
        assert np.isclose(r["DT"], r["large_step"] * 0.1) and r["ratio"] >= 0.999  # no scheme beats the floor
        assert 0 <= r["sigma_min"] <= 1.0 + 1e-12
    ok = [r for r in ch["table"] if r["admissible"]]
    meet = [r for r in ok if r["ratio"] >= p.large_step_margin]
    expect = meet[0] if meet else max(ok, key=lambda r: r["ratio"])
    assert ch["large_step"] == expect["large_step"]
    # an impossible margin picks the admissible step with the largest ratio; an impossible sigma the default
    hi = choose_large_step(replace(p, large_step_margin=1e9), gal, X, c, 20)
    assert hi["large_step"] == max(ok, key=lambda r: r["ratio"])["large_step"]
    none = choose_large_step(replace(p, large_step_sigma_min=2.0), gal, X, c, 20)
    assert none["large_step"] == 3 and not any(r["admissible"] for r in none["table"])


def test_symplectic_inverse_without_dense_J_matches_the_formula():
    rng = np.random.default_rng(1)
    V = rng.normal(size=(50, 8))
    ref = canonical_J(8).T @ V.T @ canonical_J(50)
    assert np.array_equal(symplectic_inverse(V), ref)
    assert np.isclose(symplecticity_of_basis(V), np.abs(V.T @ canonical_J(50) @ V - canonical_J(8)).max())
