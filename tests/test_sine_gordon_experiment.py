"""The sine-Gordon scenario on a tiny preset: every method runs, the results are consistent with their oracles."""

import numpy as np

from sympredict.experiments.sine_gordon import PRESETS, run_sine_gordon


def test_tiny_run_is_consistent():
    r = run_sine_gordon(PRESETS["smoke"])
    assert r["fom_step_halving_estimate"] <= PRESETS["smoke"].ref_tol
    res = r["dims"][4]
    assert res["symplecticity"] < 1e-12
    gal = np.array(res["galerkin_error"])
    # the Galerkin error cannot beat the basis: at least a fraction of the snapshot projection error scale, and finite
    assert np.all(np.isfinite(gal)) and np.all(gal < 1.0)
    # RK4 / implicit midpoint at DT with DT omega_max < 1 reach the Galerkin ROM's own error (reduction floor)
    assert res["DT_omega_max"] < 1
    assert np.allclose(res["galerkin_rk4_at_DT_error"], gal, rtol=0.1)
    assert np.allclose(res["deim_error"], gal, rtol=0.5)
    assert res["galerkin_energy_error_long"] < 1e-3
    assert len(res["energy"]["galerkin"]) == len(res["energy"]["t"]) == PRESETS["smoke"].long_factor * (len(res["curves"]["t"]) - 1) + 1
    for data in ("reduced", "projected"):
        k = res[f"kernel_{data}"]
        assert k["centers"] <= PRESETS["smoke"].max_centers
        assert (k["failure"] is None) == (k["time_per_trajectory"] is not None)
        if k["failure"] is None:
            assert len(res["curves"][f"kernel_{data}"]) == len(res["curves"]["t"])
    assert {row["N"] for row in r["cost_vs_N"]} == set(PRESETS["smoke"].cost_N)
