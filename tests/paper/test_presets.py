"""The scenarios' presets, read from ``sympredict_paper/presets/*.toml``: the same sizes the runs that wrote the docs'
numbers used, and a file's mistakes refused with a message that names the file, the preset and the key."""

import dataclasses
import hashlib
import json
from pathlib import Path

import pytest

from sympredict_paper import henon_heiles, pendulum, sine_gordon, wave
from sympredict_paper import presets as presets_module
from sympredict_paper.presets import load_presets

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = {"pendulum": pendulum, "sine_gordon": sine_gordon, "wave": wave, "henon_heiles": henon_heiles}

#: sha256 (first 16 hex digits) of ``repr(PRESETS)`` per scenario: the values and types (2.0 is not 2, a tuple is
#: no list) of the presets as the Python tables held them before they moved to the TOML files.  A changed preset
#: changes what the runs recorded in docs/data reproduce: change it with a rerun, then the fingerprint.
FINGERPRINTS = {
    "pendulum": "dc4623ee79f0a71d",
    "sine_gordon": "a87b569b11a5e383",
    "wave": "5ce3eb82c39dfb93",
    "henon_heiles": "157f2e483e1d6da9",
}


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_the_presets_are_those_of_the_recorded_runs(scenario):
    presets = SCENARIOS[scenario].PRESETS
    assert {"smoke", "quick", "paper"} <= set(presets)
    assert hashlib.sha256(repr(presets).encode()).hexdigest()[:16] == FINGERPRINTS[scenario]
    for name, preset in presets.items():  # every value of the class's type (a default's type where it has one)
        for f in dataclasses.fields(preset):
            value, default = getattr(preset, f.name), f.default
            if default is not dataclasses.MISSING and default is not None:
                assert type(value) is type(default), (scenario, name, f.name, value)


@pytest.mark.parametrize("scenario", ["pendulum", "wave"])
def test_the_quick_presets_are_those_the_docs_quick_run_recorded(scenario):
    """docs/data/quick_run.json records the quick presets of the run whose numbers and figures the docs show."""
    recorded = json.loads((ROOT / "docs" / "data" / "quick_run.json").read_text())[scenario]["preset"]
    assert recorded == json.loads(json.dumps(dataclasses.asdict(SCENARIOS[scenario].PRESETS["quick"])))


def test_based_on_starts_from_an_earlier_preset():
    p = sine_gordon.PRESETS
    assert p["smoke-breather"] == dataclasses.replace(
        p["smoke"], initial="breather", n_points=80, length=16.0, T=8.0, omega_range=(0.8, 0.9)
    )
    assert p["quick"] == sine_gordon.SineGordonPreset(kernel_split="quadratic-mass", large_step_split="auto")


@pytest.mark.parametrize(
    "text, match",
    [
        ("[smoke]\nn_gird = 3\n", r"pendulum_bad.toml \[smoke\]: \['n_gird'\] are no fields of PendulumPreset"),
        (
            "[smoke]\nn_grid = 3.0\n",
            r"\[smoke\]: n_grid = 3.0 is of type float, the field's type is int \(TOML: an integer\)",
        ),
        ("[smoke]\nn_grid = true\n", r"n_grid = True is of type bool, the field's type is int"),
        ("[smoke]\nhorizon = '2'\n", r"horizon = '2' is of type str, the field's type is float"),
        ("[smoke]\neps = 0.2\n", r"eps = 0.2 is of type float, the field's type is tuple \(TOML: an array\)"),
        ("[a]\nbased_on = 'b'\n", r"\[a\]: based_on = 'b' names no earlier preset"),
    ],
)
def test_a_files_mistakes_are_refused_by_name(monkeypatch, tmp_path, text, match):
    (tmp_path / "pendulum_bad.toml").write_text(text)
    monkeypatch.setattr(presets_module.resources, "files", lambda package: tmp_path)
    with pytest.raises(ValueError, match=match):
        load_presets("pendulum_bad", pendulum.PendulumPreset)


def test_a_float_field_takes_an_integer_as_float(monkeypatch, tmp_path):
    (tmp_path / "p.toml").write_text("[a]\nn_grid = 3\nmax_centers = 10\nn_val = 5\nhorizon = 2\n")
    monkeypatch.setattr(presets_module.resources, "files", lambda package: tmp_path)
    a = load_presets("p", pendulum.PendulumPreset)["a"]
    assert a.horizon == 2.0 and type(a.horizon) is float and type(a.n_grid) is int
