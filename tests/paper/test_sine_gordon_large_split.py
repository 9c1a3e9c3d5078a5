"""Issue 15, the large-step regime with the exact linear flow split off the FOM-data kernel
(``large_step_split``): the training rule checks existence on S's pairs, and the experiment's large-step kernel
is then a SplitKernelPredictor."""

from dataclasses import replace

import numpy as np
import pytest

from sympredict_paper import sine_gordon as sg
from sympredict_paper.sine_gordon import PRESETS, choose_large_step


@pytest.fixture(scope="module")
def small(small_sine_gordon):
    """(conftest.small_sine_gordon) a small FOM, a 2n = 6 basis from 4 trajectories, its Galerkin ROM."""
    return small_sine_gordon


def test_rule_checks_existence_on_the_split_pairs(small):
    """Oracle: on trajectories of the linear flow expm(t J A(c)) itself, S's pairs are identical (S = id), so
    sigma_min((I + M) / 2) = 1 at every DT with the split, while without it the fastest mode's |cos(omega DT / 2)|
    drops below 1 (the raw step turns it)."""
    fom, gal, X, c = small
    quad = gal.quadratic_part(mass=True)
    y0 = gal.project(X[:, 0])
    Y = [y0]
    L = quad.propagator(c[:, None], 0.1)
    for _ in range(20):
        Y.append(np.einsum("bij,bj->bi", L, Y[-1]))
    Y = np.stack(Y, axis=1)
    Xlin = gal.reconstruct(Y)
    assert np.allclose(gal.project(Xlin), Y, atol=1e-10)  # the rule projects: it must see these very states
    p = replace(PRESETS["smoke"], large_step=3, large_step_candidates=(5, 10))
    split = choose_large_step(p, gal, Xlin, c, 20, quadratic=quad)
    raw = choose_large_step(p, gal, Xlin, c, 20)
    for r in split["table"]:
        assert r["sigma_min"] == pytest.approx(1.0, abs=1e-6) and r["admissible"]
    assert min(r["sigma_min"] for r in raw["table"]) < 0.99
    # the margin part of the rule does not depend on the split (classical schemes and floor only)
    assert [r["ratio"] for r in split["table"]] == pytest.approx([r["ratio"] for r in raw["table"]])
    # symplectic-Euler existence (dp1/dp0) on S's pairs: identity as well
    se = choose_large_step(p, gal, Xlin, c, 20, quadratic=quad, update="symplectic_euler")
    assert all(r["sigma_min"] == pytest.approx(1.0, abs=1e-6) for r in se["table"])


def test_large_step_split_fits_a_split_kernel(small, monkeypatch):
    fom, gal, X, c = small
    p = replace(PRESETS["smoke"], large_step=5, large_step_candidates=(), large_step_split="quadratic-mass", repeats=1)
    seen = []
    fit = sg._fit_kernel

    def spy(*args, **kwargs):  # records the quadratic part handed to the one fit routine
        seen.append(kwargs.get("quadratic"))
        return fit(*args, **kwargs)

    monkeypatch.setattr(sg, "_fit_kernel", spy)
    out = sg._large_step(p, gal, X[::2], c[::2], X[1::2], c[1::2], 20)
    assert out["split"] == "quadratic-mass" and out["DT"] == pytest.approx(0.5)
    assert seen and all(q is not None for q in seen)
    k = out["kernel_projected_midpoint"]
    assert (k["failure"] is None) == isinstance(k["error"], list)
    if k["failure"] is None:  # no ROM in this basis beats the snapshot projection
        assert all(e >= 0.999 * f for e, f in zip(k["error"], out["projection_error"]))
    with pytest.raises(ValueError):
        sg._large_step(replace(p, large_step_split="cubic"), gal, X[::2], c[::2], X[1::2], c[1::2], 20)


def test_auto_prefers_the_unsplit_kernel_and_falls_back_to_the_split_one(small):
    """large_step_split='auto' (training trajectories only): the unsplit (non-intrusive) kernel wherever the rule
    finds an admissible step with the margin; the split one where only it does; both tables recorded."""
    fom, gal, X, c = small
    p = replace(PRESETS["smoke"], large_step=3, large_step_candidates=(5, 10))
    quad = gal.quadratic_part(mass=True)
    raw = choose_large_step(p, gal, X, c, 20)
    split = choose_large_step(p, gal, X, c, 20, quadratic=quad)
    # margin 0: the unsplit rule meets it wherever a step is admissible
    assert any(r["admissible"] for r in raw["table"])
    p0 = replace(p, large_step_margin=0.0)
    kind, _, choice = sg._choose_large_step_split(p0, gal, X, c, 20)
    assert kind == "none" and choice["large_step"] == choose_large_step(p0, gal, X, c, 20)["large_step"]
    assert set(choice["tables"]) == {"none"}  # the split rule is not needed then
    # a margin no step reaches: the unsplit rule's fallback, whatever the split rule says
    pinf = replace(p, large_step_margin=np.inf)
    kind, _, choice = sg._choose_large_step_split(pinf, gal, X, c, 20)
    assert kind == "none" and choice["large_step"] == choose_large_step(pinf, gal, X, c, 20)["large_step"]
    # the unsplit rule cannot meet the margin when no raw step is admissible; the split one then does
    strict = replace(p, large_step_sigma_min=1.01 * max(r["sigma_min"] for r in raw["table"]), large_step_margin=0.0)
    assert any(
        r["sigma_min"] >= strict.large_step_sigma_min for r in split["table"]
    )  # this data lets the split through
    kind, _, choice = sg._choose_large_step_split(strict, gal, X, c, 20)
    assert kind == "quadratic-mass" and set(choice["tables"]) == {"none", "quadratic-mass"}
    assert choice["table"] == choose_large_step(strict, gal, X, c, 20, quadratic=quad)["table"]
