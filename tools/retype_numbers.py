"""Retype the numbers the docs type beside their ``{json}`` roles after a source was rerun.

    .venv/bin/python tools/retype_numbers.py quick_run.json          # only roles into this source
    .venv/bin/python tools/retype_numbers.py quick_run.json --dry-run

A role ``{json}`TEXT <FILE:EXPR>``` shows ``TEXT`` and the build checks its number against the source
(``docs/_ext/jsondata.py``).  When the source is rewritten by a new run, every typed number that no longer
agrees is rewritten here in the same form (digits after the point, exponent, thousands separators, sign, the
text around it); numbers that still agree are left as typed.  Prints each change as ``page: old -> new``.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import jsondata  # noqa: E402

ROLE = re.compile(r"\{json\}`([^`<]+?) <([^`:]+):([^`]+)>`")
NUMBER = re.compile(r"[+\-−]?\d[\d,]*(?:\.\d+)?(?:[eE][+\-]?\d+)?")


def retype(typed: str, value: float) -> str:
    """``typed`` with its one number replaced by ``value`` written in the same form."""
    match = NUMBER.search(typed)
    text = match.group(0)
    mantissa, _, exponent = text.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    sign = "+" if text.startswith("+") and value >= 0 else ""
    if exponent:
        new = f"{value:.{decimals}e}"
        base, _, exp = new.partition("e")
        new = f"{base}e{int(exp)}"
    elif "," in text:
        new = f"{value:,.{decimals}f}"
    else:
        new = f"{value:.{decimals}f}"
    if text.startswith("−"):
        new = new.replace("-", "−")
    return typed[: match.start()] + sign + new + typed[match.end() :]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", help="the JSON file under docs/data/ whose roles to retype")
    parser.add_argument("--dry-run", action="store_true")
    args = parser.parse_args(argv)
    data = jsondata.load(DOCS / "data" / args.source)
    changed = 0
    for page in sorted(DOCS.rglob("*.md")):
        text = page.read_text(encoding="utf-8")

        def fix(m):
            nonlocal changed
            typed, source, expr = m.group(1), m.group(2), m.group(3)
            if source != args.source:
                return m.group(0)
            value = jsondata.evaluate(data, expr)
            try:
                jsondata.check_typed(typed, value)
                return m.group(0)
            except jsondata.JsonDataError:
                new = retype(typed, float(value))
                jsondata.check_typed(new, value)  # the rewritten text must pass the build's own check
                print(f"{page.relative_to(ROOT)}: {typed} -> {new}")
                changed += 1
                return f"{{json}}`{new} <{source}:{expr}>`"

        new_text = ROLE.sub(fix, text)
        if new_text != text and not args.dry_run:
            page.write_text(new_text, encoding="utf-8")
    print(f"{changed} typed number(s) {'to retype' if args.dry_run else 'retyped'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
