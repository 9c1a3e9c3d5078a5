"""The sine-Gordon scenario on the smoke preset: every method runs, results agree with their oracles, and the
figures show the numbers of the results file."""

import json

import numpy as np
import pytest

from sympredict_paper import plotting, report
from sympredict_paper.sine_gordon import PRESETS, run_sine_gordon


@pytest.fixture(scope="module")
def smoke():
    return json.loads(json.dumps(run_sine_gordon(PRESETS["smoke"])))  # as written to results.json (string keys)


def test_smoke_run_is_consistent(smoke):
    r = smoke
    assert r["fom_step_halving_estimate"] <= PRESETS["smoke"].ref_tol
    res = r["dims"]["4"]
    assert res["symplecticity"] < 1e-12
    gal = np.array(res["galerkin_error"])
    assert np.all(np.isfinite(gal)) and np.all(gal < 1.0)
    # with DT omega_max < 1, RK4 at DT reaches the Galerkin ROM's own error (the reduction floor)
    assert res["DT_omega_max"] < 1
    assert np.allclose(res["galerkin_rk4_at_DT_error"], gal, rtol=0.1)
    assert np.allclose(res["deim_error"], gal, rtol=0.5)
    assert res["galerkin_energy_error_long"] < 1e-3
    assert (
        len(res["energy"]["galerkin"])
        == len(res["energy"]["t"])
        == PRESETS["smoke"].long_factor * (len(res["curves"]["t"]) - 1) + 1
    )
    for data in ("reduced", "projected"):
        k = res[f"kernel_{data}"]
        assert k["centers"] <= PRESETS["smoke"].max_centers
        assert (k["failure"] is None) == (k["time_per_trajectory"] is not None)
        if k["failure"] is None:
            assert np.isclose(np.mean(res["curves"][f"kernel_{data}"]), np.mean(k["error"]))
    assert {row["N"] for row in r["cost_vs_N"]} == set(PRESETS["smoke"].cost_N)
    for row in r["cost_vs_N"]:  # each N has its own ROMs, as accurate as at N = n_points (the grid change is tiny)
        assert row["galerkin_error"] < 1.0 and row["deim_error"] < 1.0
        assert all(
            row[k] > 0 for k in ("galerkin_rk4", "galerkin_rk4_at_DT", "galerkin_im", "deim_rk4", "reconstruction")
        )
    at_n0 = next(row for row in r["cost_vs_N"] if row["N"] == PRESETS["smoke"].n_points and row["dim"] == 4)
    assert np.isclose(at_n0["galerkin_error"], np.median(res["galerkin_error"]), rtol=1e-6)
    ls = res["large_step"]  # one step per DT_large: errors on that grid, the projection error is the floor of every ROM
    assert (
        ls["DT"] == pytest.approx(PRESETS["smoke"].large_step * PRESETS["smoke"].DT)
        and len(ls["projection_error"]) == 2
    )
    k = ls["kernel_projected_midpoint"]
    assert (k["failure"] is None) == isinstance(k["error"], list)
    if k["failure"] is None:  # no ROM in this basis beats the snapshot projection (up to the grid's round-off)
        assert all(e >= 0.999 * f for e, f in zip(k["error"], ls["projection_error"]))
    assert all(e >= 0.999 * f for e, f in zip(ls["galerkin_error"], ls["projection_error"]))
    dd = res["data_driven"]  # pyMOR's DataDrivenReductor runs on the same projected data
    assert dd["failure"] is None, dd["failure"]
    assert len(dd["error"]) == PRESETS["smoke"].n_test and np.isclose(
        np.mean(res["curves"]["data_driven"]), np.mean(dd["error"])
    )


def test_figures_show_the_results(smoke):
    figs = report.sine_gordon_figures(smoke)
    res = smoke["dims"]["4"]
    data = plotting.figure_data(figs["sine_gordon_error_over_time_2n4"])
    lines = {ln["label"]: ln for ln in data["axes"][0]["lines"]}
    assert np.allclose(lines["Galerkin ROM (implicit midpoint, DT/r)"]["y"], res["curves"]["galerkin"][1:])
    assert np.allclose(lines["DEIM ROM"]["y"], res["curves"]["deim"][1:])
    if res["kernel_projected"]["failure"] is None:
        assert np.allclose(lines["kernel ROM (projected FOM data)"]["y"], res["curves"]["kernel_projected"][1:])
    sa = {ln["label"]: ln for ln in plotting.figure_data(figs["sine_gordon_speed_accuracy"])["axes"][0]["lines"]}
    assert np.isclose(sa["Galerkin ROM (IM)"]["y"][0], np.median(res["galerkin_error"]))
    assert np.isclose(sa["Galerkin ROM (IM)"]["x"][0], res["galerkin_time_per_trajectory"])
    cost = {ln["label"]: ln for ln in plotting.figure_data(figs["sine_gordon_cost_vs_N"])["axes"][0]["lines"]}
    rows = sorted((r["N"], r["galerkin_rk4"]) for r in smoke["cost_vs_N"] if r["dim"] == 4)
    assert np.allclose(cost["Galerkin RK4, 2n=4"]["x"], [n for n, _ in rows])
    assert np.allclose(cost["Galerkin RK4, 2n=4"]["y"], [t for _, t in rows])
    # every method timed at every N, with its own ROM there: the kernel line shows the per-N times of the results
    krows = sorted((r["N"], r["kernel"]) for r in smoke["cost_vs_N"] if r["dim"] == 4 and r["kernel"] is not None)
    if krows:
        assert np.allclose(cost["kernel, Galerkin data, 2n=4"]["y"], [t for _, t in krows])
    be = smoke["break_even"]["4"]["kernel"]
    if be["flat_ratio"] is not None:
        ts = [t for _, t in krows]
        assert np.isclose(be["flat_ratio"], ts[-1] / ts[0])
        assert be["error"] == [
            r["kernel_error"] for r in sorted(smoke["cost_vs_N"], key=lambda r: r["N"]) if r["dim"] == 4
        ]
    sn = plotting.figure_data(figs["sine_gordon_snapshots"])
    assert np.allclose(sn["axes"][1]["lines"][0]["y"], res["snapshots"]["fom"][1])
    ls = res["large_step"]
    if ls["kernel_projected_midpoint"]["failure"] is None:  # the claim's evidence shows the results' numbers
        big = next(c for c in report.sine_gordon_claims(smoke) if "large-step" in c["claim"])
        assert f"{ls['kernel_projected_midpoint']['error'][0]:.3f}" in big["evidence"]
    claims = report.sine_gordon_claims(smoke)
    assert len(claims) == 7 and all(isinstance(c["holds"], bool) for c in claims)
    md = "\n".join(report.sine_gordon_markdown(smoke))
    assert f"{np.median(res['galerkin_error']):.2e}" in md
    for f in figs.values():
        plotting.plt.close(f)


@pytest.mark.slow
def test_cli_smoke_run(tmp_path):
    from sympredict_paper.cli import main

    assert main(["run", "sine-gordon", "--preset", "smoke", "--out", str(tmp_path / "run")]) == 0
    out = tmp_path / "run"
    results = json.loads((out / "results.json").read_text())
    s = results["results"]["sine-gordon"]
    fig = json.loads((out / "sine_gordon_error_over_time_2n4.json").read_text())
    lines = {ln["label"]: ln for ln in fig["axes"][0]["lines"]}
    assert np.allclose(lines["Galerkin ROM (implicit midpoint, DT/r)"]["y"], s["dims"]["4"]["curves"]["galerkin"][1:])
    assert any("sine-Gordon" in c["claim"] for c in results["claims"])


def test_grid_interpolation_and_break_even_oracles():
    from sympredict_paper.sine_gordon import _interpolation_matrix, break_even

    x0 = 20.0 * np.arange(1, 50) / 50  # Dirichlet grid of N = 49 on (0, 20)
    assert np.allclose(_interpolation_matrix(x0, x0, 20.0).toarray(), np.eye(49))
    x1 = 20.0 * np.arange(1, 200) / 200
    f = lambda x: x * (20.0 - x)  # zero at both ends; linear interpolation errs by at most h^2 / 8 max|f''| = h^2 / 4
    err = np.abs(_interpolation_matrix(x0, x1, 20.0) @ f(x0) - f(x1)).max()
    assert 0 < err <= (20.0 / 50) ** 2 / 4 + 1e-12
    lin = lambda x: np.minimum(x, 20.0 - x)  # exact where the kinks are grid points
    assert np.allclose(_interpolation_matrix(x0, x1, 20.0) @ lin(x0), lin(x1))
    # break-even of a Galerkin cost exactly a + b N against a flat kernel cost: N* = (t_k - a) / b
    rows = [
        {
            "N": N,
            "dim": 4,
            "galerkin_rk4_at_DT": 1e-3 + 2e-6 * N,
            "galerkin_rk4": 0.0,
            "galerkin_error": 0.1,
            "kernel": 5e-3,
            "kernel_error": 0.1,
            "kernel_projected": None,
            "kernel_projected_error": None,
        }
        for N in (100, 400, 1600)
    ]
    b = break_even(rows, {4: 0.5})[4]
    assert b["galerkin_variant"] == "galerkin_rk4_at_DT"
    assert np.isclose(b["kernel"]["N_star"], 2000.0) and np.isclose(b["kernel"]["flat_ratio"], 1.0)
    assert b["kernel_projected"]["N_star"] is None


def test_energy_claim_applies_the_boundedness_criterion(smoke):
    from sympredict_paper.sine_gordon import energy_boundedness

    K = int(round(PRESETS["smoke"].T / PRESETS["smoke"].DT))
    res = smoke["dims"]["4"]
    per = res["energy_per_test"]
    assert len(per["galerkin"]) == PRESETS["smoke"].n_test and len(per["galerkin"][0]) == len(res["energy"]["t"])
    assert np.allclose(
        np.max(per["galerkin"], axis=0), res["energy"]["galerkin"]
    )  # the figure shows the max over tests
    assert energy_boundedness(per["galerkin"], K)["all_bounded"]  # the Galerkin ROM conserves H up to its step error
    claim = next(c for c in report.sine_gordon_claims(smoke) if "energy error of the kernel ROMs" in c["claim"])
    kernels = [
        energy_boundedness(per[k], K)["all_bounded"] if k in per else False
        for k in ("kernel_reduced", "kernel_projected")
    ]
    assert claim["holds"] == all(kernels)
    assert res["energy_bounded"]["galerkin"]["all_bounded"]


@pytest.mark.filterwarnings("ignore::sympredict.exceptions.ExtrapolationWarning")  # the 10 T rollout leaves the data
def test_kernel_update_reaches_both_kernel_roms():
    """``kernel_update`` switches the learned maps at ``DT`` to the symmetric form (the fitted models say so),
    and the smoke case still tracks the Galerkin ROM's reduction error with it."""
    r = run_sine_gordon(PRESETS["smoke"], kernel_update="midpoint", large_step=0)
    for res in r["dims"].values():
        for key in ("kernel_reduced", "kernel_projected"):
            assert res[key]["update"] == "midpoint"
            assert res[key]["failure"] is None and np.all(np.isfinite(res[key]["error"]))
