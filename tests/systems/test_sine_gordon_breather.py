"""The sine-Gordon scenario with breathers as initial data (issue 15): the initial states are the exact breathers,
the FOM follows the closed form, and the smoke-sized breather run is consistent end to end."""

import json

import numpy as np
import pytest

from sympredict_paper import report
from sympredict_paper.sine_gordon import PRESETS, initial_states, run_sine_gordon, second_parameter
from sympredict.systems.sine_gordon import SineGordonFOM


def test_breather_initial_states_are_the_exact_breathers_at_t0():
    p = PRESETS["breather"]
    fom = SineGordonFOM(n_points=300, length=p.length)
    c, w = np.array([0.8, 1.0, 1.2]), np.array([0.6, 0.75, 0.9])
    X0 = initial_states(fom, p, c, w)
    for x0, ci, wi in zip(X0, c, w):
        assert np.allclose(x0, fom.breather_exact([0.0], ci, wi)[0], atol=1e-14)
        assert np.all(x0[: fom.n_points] == 0) and x0[fom.n_points :].max() > 0  # at its zero crossing
    # the default family is unchanged: amplitude * sech(x/2) cos(x)
    a = np.array([0.5, 1.5])
    assert np.allclose(initial_states(fom, PRESETS["quick"], c[:2], a), a[:, None] * fom.sech_cos(2.0, 1.0))
    assert second_parameter(p) == ("omega", p.omega_range) and second_parameter(PRESETS["quick"])[0] == "amplitude"
    with pytest.raises(ValueError):
        second_parameter(PRESETS["quick"].__class__(initial="kink"))


def test_breather_preset_covers_one_period_and_decays_at_the_boundary():
    """The preset's physics: ``T`` covers one period of the slowest breather, the widest one has decayed at ``x = 0``."""
    p = PRESETS["breather"]
    assert p.T >= 2 * np.pi / min(p.omega_range)
    assert PRESETS["smoke-breather"].T >= 2 * np.pi / min(PRESETS["smoke-breather"].omega_range)
    k = np.sqrt(1 - max(p.omega_range) ** 2)
    assert 1 / np.cosh(k * (p.length / 2) / max(p.c_range)) < 0.01


def test_fom_breather_follows_the_closed_form_over_one_period():
    """Oracle: the FOM from the breather initial state against ``breather_exact`` over one period, error falling
    with ``dx`` (finite domain and central differences: small, not zero)."""
    errs = []
    for N in (200, 400):
        fom = SineGordonFOM(n_points=N, length=30.0)
        c, w, dt, K = 1.1, 0.8, 0.1, 79  # 2 pi / 0.8 = 7.85
        X = fom.reference_trajectory(
            initial_states(fom, PRESETS["breather"], [c], [w]), np.array([c]), dt, K, tol=1e-8
        )[0]
        E = fom.breather_exact(dt * np.arange(K + 1), c, w)
        errs.append(np.abs(X - E).max() / np.abs(E).max())
    assert errs[0] < 3e-3 and errs[1] < 0.5 * errs[0]


@pytest.fixture(scope="module")
def smoke():
    return json.loads(json.dumps(run_sine_gordon(PRESETS["smoke-breather"])))  # as written to results.json


@pytest.mark.filterwarnings("ignore::sympredict.exceptions.ExtrapolationWarning")
def test_smoke_breather_run_is_consistent(smoke):
    p = PRESETS["smoke-breather"]
    r = smoke
    assert r["second_parameter"] == "omega" and "test_amplitude" not in r
    assert all(p.c_range[0] <= c <= p.c_range[1] for c in r["test_c"])
    assert all(p.omega_range[0] <= w <= p.omega_range[1] for w in r["test_omega"])
    assert r["fom_step_halving_estimate"] <= p.ref_tol
    res = r["dims"]["4"]
    gal = np.array(res["galerkin_error"])
    assert np.all(np.isfinite(gal)) and np.all(gal < 1.0)
    assert np.allclose(res["deim_error"], gal, rtol=0.5)
    for data in ("reduced", "projected"):
        k = res[f"kernel_{data}"]
        assert (k["failure"] is None) == (k["time_per_trajectory"] is not None)
        if k["failure"] is None:
            assert np.isclose(np.mean(res["curves"][f"kernel_{data}"]), np.mean(k["error"]))
    # a time-periodic state whose period the training covers: the projected FOM's energy stays at its [0, T] level
    # over 10 T (with the dispersive default family it drifts 12-230x; the structural point of this scenario)
    assert res["energy_bounded"]["galerkin"]["all_bounded"]
    assert res["energy_bounded"]["projected_fom"]["all_bounded"]
    ls = res["large_step"]
    assert all(e >= 0.999 * f for e, f in zip(ls["galerkin_error"], ls["projection_error"]))
    k = ls["kernel_projected_midpoint"]
    if k["failure"] is None:
        assert all(e >= 0.999 * f for e, f in zip(k["error"], ls["projection_error"]))
    dd = res["data_driven"]  # pyMOR's DataDrivenReductor on (c, omega)
    assert dd["failure"] is None, dd["failure"]
    assert len(dd["error"]) == p.n_test
    claims = report.sine_gordon_claims(smoke)
    assert len(claims) == 7 and all(isinstance(c["holds"], bool) for c in claims)
    md = "\n".join(report.sine_gordon_markdown(smoke))
    assert "breathers" in md and f"{np.median(gal):.2e}" in md


def test_cli_rejects_breather_outside_sine_gordon(tmp_path, capsys):
    from sympredict_paper.cli import main

    assert main(["run", "pendulum", "--quick", "--initial", "breather", "--out", str(tmp_path / "x")]) == 2
    assert main(["run", "sine-gordon", "--paper", "--initial", "breather", "--out", str(tmp_path / "y")]) == 2
    assert "--initial breather" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_smoke_breather_run(tmp_path):
    from sympredict_paper.cli import main

    assert (
        main(["run", "sine-gordon", "--preset", "smoke", "--initial", "breather", "--out", str(tmp_path / "run")]) == 0
    )
    results = json.loads((tmp_path / "run" / "results.json").read_text())
    s = results["results"]["sine-gordon"]
    assert s["preset"]["initial"] == "breather" and s["second_parameter"] == "omega"
    assert any("sine-Gordon" in c["claim"] for c in results["claims"])
