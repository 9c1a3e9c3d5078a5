"""The pages render as written: no stray code fences, no directive or role left as literal text.

``sphinx -W`` does not catch a fence that is never closed (``` followed by text on the closing
line): the rest of the section becomes one code block and the reader sees the literal
```` ```{sympredict-help} predict ````.  The build here is the documentation's own (``docs/conf.py``),
into a temporary folder; the HTML of every page is searched for such leftovers.
"""

import html
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})(.*)$")
#: What only unrendered MyST leaves in HTML: a fence, or a directive/role name in braces before a backtick.
LEFTOVER = re.compile(r"`{3,}|\{[a-z][\w-]*\}`")


def fence_problems(text: str) -> list[str]:
    """Fences that do not close cleanly: a closing fence with text after it, or a fence never closed."""
    problems, open_fence = [], None
    for n, line in enumerate(text.split("\n"), 1):
        m = FENCE.match(line)
        if open_fence is None:
            if m:
                open_fence = (n, m.group(2))
            elif "```" in line:
                problems.append(f"line {n}: a fence inside a line: {line.strip()[:60]!r}")
            continue
        if m and m.group(2)[0] == open_fence[1][0] and len(m.group(2)) >= len(open_fence[1]):
            if m.group(3).strip():
                problems.append(f"line {n}: text after a closing fence: {line.strip()[:60]!r}")
            else:
                open_fence = None
    if open_fence is not None:
        problems.append(f"line {open_fence[0]}: a fence that is never closed")
    return problems


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_fence_closes_on_a_line_of_its_own(page):
    problems = fence_problems(page.read_text(encoding="utf-8"))
    assert not problems, f"{page.relative_to(ROOT)}:\n" + "\n".join(problems)


@pytest.mark.parametrize(
    "text", ["```bash\nls\n``` On a terminal\n\n```{x} y\n```\n", "```python\nx = 1\n", "text ```inline``` fence\n"]
)
def test_the_fence_check_catches_broken_fences(text):
    assert fence_problems(text)


def test_the_fence_check_spares_nested_and_indented_fences():
    assert not fence_problems("````markdown\n```python\nx\n```\n````\n\n   ```text\n   y\n   ```\n")


def leftovers(page_html: str) -> list[str]:
    """Literal fences or ``{name}``` ` text in a rendered page (HTML entities decoded)."""
    body = re.sub(r"<script.*?</script>", "", page_html, flags=re.DOTALL)
    return sorted({m.group(0) for m in LEFTOVER.finditer(html.unescape(body))})


def test_the_html_check_catches_an_unrendered_directive():
    assert leftovers("<pre>```{sympredict-help} predict\n```</pre>") == ["```"]
    assert leftovers("<p>```{sympredict-help} predict</p>")
    assert leftovers("<p>see {json}`runtimes.json:demo.cold_s`</p>")
    assert not leftovers("<p>a <code>dict</code> {a: 1} and `x`</p>")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("html")
    proc = subprocess.run(
        [sys.executable, "-m", "sphinx", "-E", "-q", "-b", "html", str(ROOT / "docs"), str(out)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


def test_rendered_pages_hold_no_stray_fences_or_directives(built):
    pages = [
        p for p in built.rglob("*.html") if not {"_modules", "_sources", "_static"} & set(p.relative_to(built).parts)
    ]
    assert len(pages) > 20
    bad = {p.relative_to(built).as_posix(): found for p in pages if (found := leftovers(p.read_text(encoding="utf-8")))}
    assert not bad, bad
