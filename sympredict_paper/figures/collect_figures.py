"""Copy the figures shown in the documentation from a results folder into docs/figures/.

Run, after ``sympredict-paper run all --quick --out DIR`` and
``sympredict-paper run henon-heiles --quick --out HH`` (``run all`` does not run
Hénon–Heiles)::

    python sympredict_paper/figures/collect_figures.py DIR HH

Each figure is taken from the first folder that has it.
The figures to copy are those that ``docs/explanation/figures.md`` shows (every
``figures/NAME.png`` in it), so that page is the one list.  Each PNG is stored
with a 256-colour palette (line plots look the same at a third of the size;
``--no-shrink`` copies the files unchanged).  ``docs/figures/source.txt``
records, per folder, the command of the run (from its ``results.json``), when
its files were written and which figures came from it, and the commit checked
out when the figures were collected.

Exit status 1 if a figure the page shows is in none of the folders (nothing is
copied then); PNGs in the folders that the page does not show are listed, not copied.
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

DOCS = Path(__file__).resolve().parents[2] / "docs"
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
        im.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
            dst, optimize=True
        )


def _commit() -> str:
    """The checked-out commit (with ``-dirty`` for uncommitted changes), or ``unknown``."""
    try:
        out = subprocess.run(
            ["git", "describe", "--always", "--dirty", "--abbrev=12"],
            cwd=DOCS,
            capture_output=True,
            text=True,
            check=True,
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _source_text(folders: list[tuple[Path, str, list[str]]], checkout: str) -> str:
    """The lines of ``source.txt``: per folder its command, file dates and figures; the commit at collection time."""
    lines = []
    for results, _given, names in folders:
        command = "unknown (no results.json in the results folder)"
        info = results / "results.json"
        if info.is_file():
            try:
                command = json.loads(info.read_text(encoding="utf-8")).get("command", command)
            except (OSError, ValueError):
                pass
        times = [p.stat().st_mtime for p in results.glob("*.png")]
        written = (
            _dt.datetime.fromtimestamp(max(times), _dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
            if times
            else "unknown"
        )
        lines += [f"command:   {command}", f"written:   {written}", f"figures:   {', '.join(names)}", ""]
    given = " ".join(g for _, g, _ in folders)
    lines.append(f"collected: python sympredict_paper/figures/collect_figures.py {given} (checkout {checkout})")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "results",
        type=Path,
        nargs="+",
        help="output folder(s) of `sympredict-paper run ... --quick --out DIR`; each figure from the first that has it",
    )
    parser.add_argument(
        "--no-shrink", action="store_true", help="copy the PNGs unchanged instead of re-encoding them with a palette"
    )
    args = parser.parse_args(argv)

    for results in args.results:
        if not results.is_dir():
            print(f"error: {results} is not a folder", file=sys.stderr)
            return 1
    names = shown_figures()
    origin = {n: next((r for r in args.results if (r / n).is_file()), None) for n in names}
    missing = [n for n, r in origin.items() if r is None]
    if missing:
        print(
            f"error: {', '.join(map(str, args.results))} lack(s) {len(missing)} figure(s) that docs/explanation/figures.md "
            f"shows: {', '.join(missing)}",
            file=sys.stderr,
        )
        print(
            "run `sympredict-paper run all --quick --out DIR` and `sympredict-paper run henon-heiles --quick --out HH` with the "
            "current code, then give both folders",
            file=sys.stderr,
        )
        return 1

    checkout = _commit()  # before the copies change the checkout
    TARGET.mkdir(exist_ok=True)
    total = 0
    for name in names:
        src, dst = origin[name] / name, TARGET / name
        if args.no_shrink:
            shutil.copyfile(src, dst)
        else:
            _shrink(src, dst)
        total += dst.stat().st_size
        print(f"{name}: {src.stat().st_size // 1024} KiB -> {dst.stat().st_size // 1024} KiB")
    used = [(r.resolve(), str(r), [n for n in names if origin[n] == r]) for r in args.results]
    (TARGET / "source.txt").write_text(_source_text([u for u in used if u[2]], checkout), encoding="utf-8")
    print(f"{len(names)} figures, {total // 1024} KiB in {TARGET}")

    stale = sorted(p.name for p in TARGET.glob("*.png") if p.name not in names)
    if stale:
        print(f"note: docs/figures/ also holds PNGs the page no longer shows (remove them?): {', '.join(stale)}")
    extra = sorted({p.name for r in args.results for p in r.glob("*.png") if p.name not in names})
    if extra:
        print(
            f"note: the folders have PNGs that docs/explanation/figures.md does not show (add them to the page to publish them): {', '.join(extra)}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
