"""README and docs describe the software as it is: no development history.

No issue or pull-request numbers, no run letters of lab notes, no dates of work,
no commit hashes, no "the target was" / "this session".  The changelog is the place
for history (and follows Keep a Changelog).
"""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "docs").rglob("*.rst"))]

HISTORY = {
    "issue number": re.compile(r"\b(?:issue|pull request|PR)s?\s*#?\d+", re.IGNORECASE),
    "#number": re.compile(r"(?<![\w(&/#])#\d+\b(?!-)"),
    "run letter": re.compile(r"\b[Rr]uns? [A-Z]\b(?![-'’])"),
    "date": re.compile(r"\b20\d\d-\d\d-\d\d\b"),
    "commit hash": re.compile(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b"),
    "history phrase": re.compile(
        r"the target was|this session|the issue'?s?\b|(?:first|second) pass\b|"
        r"the previous release|an earlier version",
        re.IGNORECASE,
    ),
}


def findings(text: str) -> list[str]:
    """``kind: match`` for every development-history reference in ``text``."""
    out = []
    for kind, pattern in HISTORY.items():
        out += [f"{kind}: {m.group(0)!r}" for m in pattern.finditer(text)]
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_development_history(page):
    bad = []
    for n, line in enumerate(page.read_text(encoding="utf-8").split("\n"), 1):
        bad += [f"line {n}: {f}" for f in findings(line)]
    assert not bad, f"{page.relative_to(ROOT)} refers to development history:\n" + "\n".join(bad)


@pytest.mark.parametrize(
    "text",
    [
        "see issue 14",
        "fixed in #12",
        "run B shows",
        "measured 2026-11-22",
        "against 75d2b66",
        "the target was 2e-5",
        "as in this session",
        "the issue's 2e-5 target",
    ],
)
def test_the_patterns_catch_history(text):
    assert findings(text)


@pytest.mark.parametrize(
    "text",
    [
        "1000000000000 bytes",
        "IMQ(0.5) kernel",
        "headings link as #1-data",
        "scenario A and scenario B",
        "a run of the pendulum",
        "deadbeef",
        "`ExactGreedy('float32')`",
        "fault E1 and F7",
    ],
)
def test_the_patterns_spare_ordinary_text(text):
    assert not findings(text)


def test_changelog_follows_keep_a_changelog():
    text = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert text.startswith("# Changelog\n") and "keepachangelog.com" in text
    versions = re.findall(r"^## \[([^\]]+)\]", text, re.MULTILINE)
    assert versions and versions[0] == "Unreleased"
    allowed = {"Added", "Changed", "Deprecated", "Removed", "Fixed", "Security"}
    sections = re.findall(r"^### (.+)$", text, re.MULTILINE)
    assert sections and set(sections) <= allowed, set(sections) - allowed
    assert not re.findall(r"^#{2,} (?!\[|(?:" + "|".join(allowed) + r")$)", text, re.MULTILINE)
