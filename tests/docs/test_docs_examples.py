"""Every Python example in README.md and docs/ runs, and prints what the page shows.

A page's ```python blocks run in order in one namespace (a fresh Python process per
page, in a temporary folder), as a reader pasting them one after the other would.
A block followed by ``<!-- expected-output -->`` and a fenced block must print that
text (doctest's comparison: whitespace normalised, ``...`` matches anything).
A block that is intentionally partial is preceded by ``<!-- skip-example: reason -->``;
the skipped blocks are counted here, so adding one is a visible change.

Errors of a fitted model depend on which centres the greedy picks, and round-off on another CPU
(another BLAS kernel) can change a late pick.  A block printing such numbers says how far they may
move, ``<!-- expected-output: factor=3 -->``: its text must match and each number in it must agree
with the page's within that factor (and have the same sign); integers still match exactly.
"""

from __future__ import annotations

import doctest
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]

SKIP = re.compile(r"<!--\s*skip-example:\s*(.+?)\s*-->")
OUTPUT = re.compile(r"<!--\s*expected-output(?::\s*factor=([0-9.]+))?\s*-->")
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
FENCE = re.compile(r"^(`{3,})\s*([\w{}-]*)")

#: pages whose examples take longer than a few seconds (minutes of training or a full-order model)
SLOW_PAGES = {
    "docs/tutorials/pendulum.md",
    "docs/tutorials/pymor_rom.md",
    "docs/reference/integrators.md",
    "docs/howto/test_your_rom.md",
}
#: the number of blocks marked skip-example, page by page
EXPECTED_SKIPS = {
    "docs/explanation/beyond.md": 1,
    "docs/howto/mpi.md": 1,
}


def parse_blocks(text: str) -> list[dict]:
    """The fenced blocks of a Markdown page: ``lang``, ``code``, ``line``, the preceding marker."""
    lines = text.split("\n")
    blocks, i, last = [], 0, ""
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            if lines[i].strip():
                last = lines[i].strip()
            i += 1
            continue
        fence, lang, start = m.group(1), m.group(2), i
        i += 1
        body = []
        while i < len(lines) and not lines[i].startswith(fence):
            body.append(lines[i])
            i += 1
        if i == len(lines):
            raise AssertionError(f"unclosed code fence opened at line {start + 1}")
        skip, output = SKIP.fullmatch(last), OUTPUT.fullmatch(last)
        blocks.append(
            {
                "lang": lang,
                "code": "\n".join(body) + "\n",
                "line": start + 1,
                "skip": skip.group(1) if skip else None,
                "output_marker": bool(output),
                "factor": float(output.group(1)) if output and output.group(1) else None,
            }
        )
        last = ""
        i += 1
    return blocks


def examples(page: Path) -> list[dict]:
    """The python/pycon blocks of ``page``, each with its expected output (or None)."""
    blocks = parse_blocks(page.read_text(encoding="utf-8"))
    out = []
    for k, b in enumerate(blocks):
        if b["output_marker"]:
            assert k > 0 and blocks[k - 1]["lang"] in ("python", "pycon"), (
                f"{page}:{b['line']}: an expected-output block must follow a python block"
            )
            continue
        if b["lang"] not in ("python", "pycon"):
            continue
        code = b["code"]
        if b["lang"] == "pycon":
            code = "".join(ex.source for ex in doctest.DocTestParser().get_examples(code))
        nxt = blocks[k + 1] if k + 1 < len(blocks) else None
        expected = nxt["code"] if nxt is not None and nxt["output_marker"] else None
        factor = nxt["factor"] if expected is not None else None
        out.append({**b, "code": code, "expected": expected, "factor": factor})
    return out


_RUNNER = textwrap.dedent("""
    import contextlib, io, json, sys, traceback, warnings
    blocks = json.load(open(sys.argv[1]))
    ns = {"__name__": "__main__"}
    results = []
    for b in blocks:
        buf = io.StringIO()
        try:
            with contextlib.redirect_stdout(buf):
                exec(compile(b["code"], b["name"], "exec"), ns)
            results.append({"out": buf.getvalue(), "error": None})
        except BaseException:
            results.append({"out": buf.getvalue(), "error": traceback.format_exc()})
            break
    json.dump(results, open(sys.argv[2], "w"))
""")


def numbers_agree(expected: str, got: str, factor: float) -> bool:
    """The same text around the numbers, integers equal, other numbers within ``factor`` (same sign)."""
    if NUMBER.sub("#", " ".join(expected.split())) != NUMBER.sub("#", " ".join(got.split())):
        return False
    for e, g in zip(NUMBER.findall(expected), NUMBER.findall(got)):
        if re.fullmatch(r"[-+]?\d+", e):
            if e != g:
                return False
            continue
        a, b = float(e), float(g)
        if a == b:
            continue
        if a == 0 or b == 0 or (a > 0) != (b > 0) or not (1 / factor <= b / a <= factor):
            return False
    return True


def _rel(page: Path) -> str:
    return page.relative_to(ROOT).as_posix()


def _params():
    for page in PAGES:
        if any(not b["skip"] for b in examples(page)):
            rel = _rel(page)
            marks = [pytest.mark.slow] if rel in SLOW_PAGES else []
            yield pytest.param(page, id=rel, marks=marks)


@pytest.mark.parametrize("page", list(_params()))
def test_page_examples_run_and_print_what_the_page_shows(page, tmp_path):
    runnable = [b for b in examples(page) if not b["skip"]]
    spec = [{"code": b["code"], "name": f"{_rel(page)}:{b['line']}"} for b in runnable]
    (tmp_path / "blocks.json").write_text(json.dumps(spec))
    (tmp_path / "runner.py").write_text(_RUNNER)
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "runner.py", "blocks.json", "results.json"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads((tmp_path / "results.json").read_text())
    checker = doctest.OutputChecker()
    flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    for b, r in zip(runnable, results):
        where = f"{_rel(page)}, block at line {b['line']}"
        assert r["error"] is None, f"{where} raised:\n{r['error']}"
        if b["expected"] is not None:
            same = (
                numbers_agree(b["expected"], r["out"], b["factor"])
                if b["factor"] is not None
                else checker.check_output(b["expected"], r["out"], flags)
            )
            assert same, f"{where} printed\n{r['out']}\nbut the page shows\n{b['expected']}"
    assert len(results) == len(runnable)


def test_skipped_examples_are_counted_and_give_a_reason():
    found = {}
    for page in PAGES:
        skipped = [b for b in examples(page) if b["skip"]]
        for b in skipped:
            assert len(b["skip"]) > 10, f"{_rel(page)}:{b['line']}: say why the example is skipped"
        if skipped:
            found[_rel(page)] = len(skipped)
    assert found == EXPECTED_SKIPS


def test_the_readme_example_shows_its_output():
    first = examples(ROOT / "README.md")[0]
    assert first["expected"] is not None, "README.md: the first Python block needs an expected-output block"
    assert "SymplecticKernelPredictor" in first["code"] and ".fit(" in first["code"]
    assert len(first["code"].strip().split("\n")) <= 20


def test_parser_reads_markers_and_outputs():
    text = (
        "<!-- skip-example: a fragment of the tutorial -->\n```python\nx\n```\n\n"
        "```python\nprint(1)\n```\n<!-- expected-output -->\n```text\n1\n```\n```pycon\n>>> print(2)\n2\n```\n"
    )
    blocks = parse_blocks(text)
    assert [b["lang"] for b in blocks] == ["python", "python", "text", "pycon"]
    assert blocks[0]["skip"] == "a fragment of the tutorial" and blocks[1]["skip"] is None
    assert blocks[2]["output_marker"] and not blocks[3]["output_marker"]


def test_numbers_agree_within_the_declared_factor_only():
    assert numbers_agree("error 6.2e-07, 300 centres", "error 9.0e-07, 300 centres", 3)
    assert not numbers_agree("error 6.2e-07, 300 centres", "error 6.2e-06, 300 centres", 3)
    assert not numbers_agree("error 6.2e-07, 300 centres", "error 6.2e-07, 299 centres", 3)
    assert not numbers_agree("error 6.2e-07", "error -6.2e-07", 3)
    assert not numbers_agree("error 6.2e-07", "drift 6.2e-07", 3)
    blocks = parse_blocks("```python\nprint(1.0)\n```\n<!-- expected-output: factor=2 -->\n```text\n1.0\n```\n")
    assert blocks[1]["output_marker"] and blocks[1]["factor"] == 2.0
