"""The SI-orbit study (sympredict_paper/studies/si_orbit.py): its unit conversion and its JSON."""

import numpy as np
import pytest

from _studies import run_study, study_module  # tests/


@pytest.fixture(scope="module")
def si():
    with study_module("si_orbit.py") as module:
        yield module


def test_canonical_units_map_the_flow_onto_the_flow(si):
    """Oracle: the exact flow in SI units equals the exact flow in canonical units (GM / GM_ref, dt / T) mapped back;
    the sampled states are bound LEO orbits of the stated radii."""
    x, gm = si.sample(50, 1)
    xc, gc, dtc = si.to_canonical(x, gm, si.DT)
    direct = si.SYSTEM.flow(x, gm[:, None], si.DT)
    via = si.from_canonical(si.SYSTEM.flow(xc, gc[:, None], dtc))
    np.testing.assert_allclose(via, direct, rtol=1e-11, atol=1e-11 * np.abs(direct).max())
    r = np.hypot(x[:, 0], x[:, 1])
    assert np.all(r > si.A_RANGE[0] * (1 - si.E_MAX) * 0.999) and np.all(r < si.A_RANGE[1] * (1 + si.E_MAX) * 1.001)
    assert np.all(si.kepler_H(x, gm[:, None]) < 0)


def test_quick_run_writes_both_configurations_and_their_ratio(tmp_path):
    data, stdout = run_study(
        "si_orbit.py", tmp_path / "out.json", "--quick", "--configs", "defaults", "defaults_canonical", "expert"
    )
    rows = data["rows"]
    assert set(rows) == {"defaults", "defaults_canonical", "expert"}
    for row in rows.values():
        assert row["n_centers"] > 0 and row["error_median"] > 0 and row["energy_median"] > 0
    # the defaults do not depend on the units (the unit-invariance oracle of tests/estimators/test_si_units.py)
    assert rows["defaults"]["error_median"] == pytest.approx(rows["defaults_canonical"]["error_median"], rel=1e-6)
    ratio = data["defaults_over_expert"]
    assert ratio["error_median"] == pytest.approx(rows["defaults"]["error_median"] / rows["expert"]["error_median"])
    assert "si_orbit.py" in data["protocol"]["command"]
