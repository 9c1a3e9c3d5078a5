"""Copy the figures shown in the documentation from a results folder into docs/figures/.

Run, after ``sympredict run all --quick --out DIR``::

    python docs/collect_figures.py DIR

The figures to copy are those that ``docs/explanation/figures.md`` shows (every
``figures/NAME.png`` in it), so that page is the one list.  Each PNG is stored
with a 256-colour palette (line plots look the same at a third of the size;
``--no-shrink`` copies the files unchanged).  ``docs/figures/source.txt``
records the command of the run (from ``DIR/results.json``), when its files
were written, and the commit checked out when the figures were collected.

Exit status 1 if a figure the page shows is missing from ``DIR`` (nothing is
copied then); PNGs in ``DIR`` that the page does not show are listed, not copied.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
PAGE = DOCS / "explanation" / "figures.md"
TARGET = DOCS / "figures"


def shown_figures(page: Path = PAGE) -> list[str]:
    """File names of the PNGs ``page`` shows, in order of appearance, without duplicates."""
    names = re.findall(r"figures/([\w.-]+\.png)", page.read_text(encoding="utf-8"))
    return list(dict.fromkeys(names))


def _shrink(src: Path, dst: Path) -> None:
    """Write ``src`` as a palette PNG (256 colours, no dithering) to ``dst``."""
    from PIL import Image  # a dependency of matplotlib

    with Image.open(src) as im:
        im.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(dst, optimize=True)


def _commit() -> str:
    """The checked-out commit (with ``-dirty`` for uncommitted changes), or ``unknown``."""
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=12"], cwd=DOCS, capture_output=True, text=True, check=True)
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _source_text(results: Path, given: str) -> str:
    """The lines of ``source.txt``: command, file dates, commit at collection time."""
    command = "unknown (no results.json in the results folder)"
    info = results / "results.json"
    if info.is_file():
        try:
            command = json.loads(info.read_text(encoding="utf-8")).get("command", command)
        except (OSError, ValueError):
            pass
    times = [p.stat().st_mtime for p in results.glob("*.png")]
    written = _dt.datetime.fromtimestamp(max(times), _dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC") if times else "unknown"
    return (
        f"command:   {command}\n"
        f"written:   {written}\n"
        f"collected: python docs/collect_figures.py {given} (checkout {_commit()})\n"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="output folder of `sympredict run all --quick --out DIR`")
    parser.add_argument("--no-shrink", action="store_true", help="copy the PNGs unchanged instead of re-encoding them with a palette")
    args = parser.parse_args(argv)

    results = args.results
    if not results.is_dir():
        print(f"error: {results} is not a folder", file=sys.stderr)
        return 1
    names = shown_figures()
    missing = [n for n in names if not (results / n).is_file()]
    if missing:
        print(f"error: {results} lacks {len(missing)} figure(s) that docs/explanation/figures.md shows: {', '.join(missing)}", file=sys.stderr)
        print("run `sympredict run all --quick --out DIR` with the current code, then try again", file=sys.stderr)
        return 1

    TARGET.mkdir(exist_ok=True)
    total = 0
    for name in names:
        src, dst = results / name, TARGET / name
        if args.no_shrink:
            shutil.copyfile(src, dst)
        else:
            _shrink(src, dst)
        total += dst.stat().st_size
        print(f"{name}: {src.stat().st_size // 1024} KiB -> {dst.stat().st_size // 1024} KiB")
    (TARGET / "source.txt").write_text(_source_text(results.resolve(), str(results)), encoding="utf-8")
    print(f"{len(names)} figures, {total // 1024} KiB in {TARGET}")

    stale = sorted(p.name for p in TARGET.glob("*.png") if p.name not in names)
    if stale:
        print(f"note: docs/figures/ also holds PNGs the page no longer shows (remove them?): {', '.join(stale)}")
    extra = sorted(p.name for p in results.glob("*.png") if p.name not in names)
    if extra:
        print(f"note: {results} has PNGs that docs/explanation/figures.md does not show (add them to the page to publish them): {', '.join(extra)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
