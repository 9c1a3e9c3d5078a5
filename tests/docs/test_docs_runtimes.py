"""Every page with something to run says how long it takes, from the measured docs/data/runtimes.json.

The docs render the seconds with the ``{json}`` role; the README, which GitHub shows unrendered, states
them as plain numbers, which must lie within 1.5x of the measured ones.
"""

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))

import measure_runtimes  # noqa: E402

RUNTIMES = json.loads((ROOT / "docs" / "data" / "runtimes.json").read_text())
PAGES = [p for p in sorted((ROOT / "docs").rglob("*.md")) if measure_runtimes.page_blocks(p)]


def test_the_runtimes_say_how_and_where_they_were_measured():
    assert RUNTIMES["command"].startswith("python tools/measure_runtimes.py") and RUNTIMES["machine"].strip()
    assert {"demo", "quick", "pages", "basis"} <= set(RUNTIMES)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_page_with_examples_states_their_measured_runtime(page):
    key = measure_runtimes.page_key(page)
    assert key in RUNTIMES["pages"], f"{key}: run python tools/measure_runtimes.py --only pages"
    assert f"runtimes.json:pages.{key}.s" in page.read_text(encoding="utf-8")


def test_the_readme_states_the_demo_times_within_the_measured_ones():
    text = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    m = re.search(
        r"takes about (\d+) s on a 2-core machine the first time, with an empty compilation cache, "
        r"and about (\d+) s after that",
        text,
    )
    assert m, "README: the sentence with the demo's times"
    demo = RUNTIMES["demo"]
    for stated, key in zip(map(float, m.groups()), ("cold_s", "warm_s")):
        assert demo[key] / 1.5 <= stated <= demo[key] * 1.5, (key, stated, demo[key])


def test_the_quick_runs_and_the_tutorials_are_timed():
    assert RUNTIMES["quick"]["pendulum"]["s"] > 0 and RUNTIMES["quick"]["wave"]["s"] > 0
    for key in ("tutorials_pendulum", "tutorials_pymor_rom", "tutorials_your_own_data"):
        assert RUNTIMES["pages"][key]["s"] > 0
